"""Real multi-light captures laid out like DiLiGenT (Shi et al., CVPR 2016 /
TPAMI 2019, "A Benchmark Dataset and Evaluation for Non-Lambertian and
Uncalibrated Photometric Stereo"):

    folder/001.png ... (16-bit RGB, one per light; order from filenames.txt if present)
    folder/light_directions.txt   L x 3 unit vectors, camera frame
    folder/light_intensities.txt  L x 3 RGB intensities
    folder/mask.png               object mask (pixels equal to the mask's maximum)
    folder/Normal_gt.mat          optional, key 'Normal_gt', H x W x 3 (MAT v5, read by a bounded
                                  parser of our own: scipy's crashes on some corrupt files)

The camera frame is x right, y up, z toward the camera, i.e. the light
stage's frame with the camera on +z.
"""

from __future__ import annotations

import dataclasses
import os
import struct
import zlib
from pathlib import Path

import numpy as np

import stage

from ._errors import ImageFormatError, check_radiance, path_inside
from ._png import read_png

__all__ = ["DiligentData", "diligent_capture", "grey_value", "is_diligent_folder", "lambert_normals", "read_diligent"]

# The benchmark's grey value: ITU-R BT.601 luma weights.
_LUMA = (0.2989, 0.5870, 0.1140)


@dataclasses.dataclass(frozen=True)
class DiligentData:
    """A DiLiGenT-style capture as plain numpy arrays.

    Attributes:
        images: ``[L, H, W, 3]`` float32, the 16-bit values divided by 65535
            (not divided by the light intensities: ``images[l] / intensities[l]``
            is the radiance per unit light intensity).
        light_directions: ``[L, 3]`` unit vectors toward each light (camera frame).
        light_intensities: ``[L, 3]`` RGB intensity of each light.
        mask: ``[H, W]`` bool, the object's pixels.
        normals_gt: ``[H, W, 3]`` ground-truth unit normals, or None if absent.
        filenames: the image file names, in light order.
    """

    images: np.ndarray
    light_directions: np.ndarray
    light_intensities: np.ndarray
    mask: np.ndarray
    normals_gt: np.ndarray | None
    filenames: tuple[str, ...]


def is_diligent_folder(folder: str | os.PathLike) -> bool:
    """A DiLiGenT-layout object folder (:func:`read_diligent`): light_directions.txt,
    light_intensities.txt and mask.png, and no capture.json."""
    folder = Path(folder)
    return (folder.is_dir() and not (folder / "capture.json").exists()
            and all((folder / f).is_file() for f in ("light_directions.txt", "light_intensities.txt", "mask.png")))


def grey_value(rgb: np.ndarray) -> np.ndarray:
    """The DiLiGenT benchmark's grey value of RGB values [..., 3]: ITU-R BT.601 luma, clipped at 1
    (full scale); the Lambertian baselines fit it."""
    return np.minimum(rgb @ np.asarray(_LUMA, rgb.dtype), 1.0)


def lambert_normals(data: DiligentData) -> np.ndarray:
    """The benchmark's baseline: grey Lambertian least squares on every light,
    float64 [P, 3] per mask pixel (albedo-scaled, not unit length)."""
    img = data.images / data.light_intensities[:, None, None, :]
    grey = grey_value(img)
    return np.linalg.lstsq(data.light_directions.astype(np.float64), grey[:, data.mask], rcond=None)[0].T


def _light_names(folder: Path) -> list[str]:
    """The light images in light order: filenames.txt if present, else the numbered PNGs sorted."""
    names_file = folder / "filenames.txt"
    if names_file.is_file():
        try:
            text = names_file.read_text(encoding="utf-8")
        except UnicodeDecodeError as err:
            raise ImageFormatError(f"{names_file}: not UTF-8 text ({err})") from None
        names = [ln.strip() for ln in text.splitlines() if ln.strip()]
        for i, name in enumerate(names):  # names come from a user's file: they must stay in the folder
            path_inside(folder, name, f"{names_file}: line {i + 1}", what="the DiLiGenT folder")
    else:
        names = sorted(p.name for p in folder.glob("*.png") if p.stem.isdigit())
    if not names:
        raise ImageFormatError(f"{folder}: no light images (expected 001.png, 002.png, ... or filenames.txt)")
    return names


def _read_lights(folder: Path, count: int) -> tuple[np.ndarray, np.ndarray]:
    """(directions [L, 3], intensities [L, 3]) from the two text tables (``stage.read_light_table``), one row
    per light image, unit directions and positive intensities."""
    dirs_path, ints_path = folder / "light_directions.txt", folder / "light_intensities.txt"
    dirs = stage.read_light_table(dirs_path, "light directions", error=ImageFormatError)
    ints = stage.read_light_table(ints_path, "light intensities", error=ImageFormatError)
    for path, arr in ((dirs_path, dirs), (ints_path, ints)):
        if arr.shape[0] != count:
            raise ImageFormatError(f"{path}: {arr.shape[0]} lights listed but {count} images found in {folder}")
    norms = np.linalg.norm(dirs, axis=1)
    if np.any(np.abs(norms - 1) > 1e-3):  # the files carry 4 decimals
        bad = int(np.argmax(np.abs(norms - 1)))
        raise ImageFormatError(f"{dirs_path}: line {bad + 1} is not a unit vector (length {norms[bad]:.4f})")
    if np.any(ints <= 0):
        raise ImageFormatError(f"{ints_path}: intensities must be positive")
    return dirs, ints


def _read_images(folder: Path, names: list[str], index: np.ndarray) -> np.ndarray:
    """The light images ``index`` as float32 [L, H, W, 3], 16-bit values / 65535, all of one size."""
    images = None
    for k, i in enumerate(index):
        path = folder / names[i]
        if not path.is_file():
            raise ImageFormatError(f"{path}: light image {i + 1} is missing (listed in filenames.txt or by number)")
        img = read_png(path)
        if img.dtype != np.uint16 or img.shape[-1] != 3:
            raise ImageFormatError(f"{path}: expected a 16-bit RGB PNG, got {img.dtype} with "
                                   f"{img.shape[-1]} channel(s)")
        if images is None:
            images = np.empty((len(index), *img.shape), np.float32)
        elif img.shape != images.shape[1:]:
            raise ImageFormatError(f"{path}: size {img.shape[:2]} differs from {images.shape[1:3]} of the first image")
        images[k] = img.astype(np.float32) / np.float32(65535.0)
    return images


def _read_mask(folder: Path, size: tuple[int, int]) -> np.ndarray:
    """mask.png's pixels equal to its maximum (all pixels without a mask file)."""
    mask_path = folder / "mask.png"
    if not mask_path.is_file():
        return np.ones(size, bool)
    m = read_png(mask_path)
    m = m.max(axis=-1) if m.ndim == 3 else m
    if m.shape != size:
        raise ImageFormatError(f"{mask_path}: mask size {m.shape} differs from image size {size}")
    return m == m.max() if m.max() > 0 else np.zeros(m.shape, bool)


# MAT v5 numeric element types (MATLAB's "MAT-File Format", Table 1-1) -> numpy dtypes.
_MAT_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 9: "f8", 12: "i8", 13: "u8"}
_MI_MATRIX, _MI_COMPRESSED = 14, 15


def _mat_elements(buf: bytes, order: str):
    """(type, payload) of each data element in ``buf``: 8-byte tags (or the 4-byte small-element form),
    payloads padded to 8 bytes but compressed ones. Raises ValueError on a tag that overruns ``buf``."""
    pos = 0
    while pos + 8 <= len(buf):
        kind, n = struct.unpack_from(order + "II", buf, pos)
        if kind >> 16:  # small data element: size in the upper half, data in the tag's second word
            yield kind & 0xFFFF, buf[pos + 4 : pos + 4 + (kind >> 16)]
            pos += 8
            continue
        if pos + 8 + n > len(buf):
            raise ValueError(f"a data element of {n} bytes overruns the file at byte {pos}")
        yield kind, buf[pos + 8 : pos + 8 + n]
        pos += 8 + n + (0 if kind == _MI_COMPRESSED else -n % 8)  # compressed elements are not padded


def _matrix_name(head: bytes, order: str) -> str | None:
    """The name of the matrix element starting ``head`` (the first bytes of one), or None."""
    if len(head) < 8 or struct.unpack_from(order + "I", head)[0] != _MI_MATRIX:
        return None
    parts = []
    try:
        for part in _mat_elements(head[8:], order):
            parts.append(part)
            if len(parts) == 3:
                break
    except ValueError:  # the head ends inside an element: what came before is enough
        pass
    return bytes(parts[2][1]).decode("latin-1") if len(parts) == 3 and parts[2][0] in (1, 2) else None


def _mat_variable(data: bytes, name: str, shape: tuple[int, ...]) -> np.ndarray | None:
    """Variable ``name`` of a MAT v5 file's bytes as float64 of ``shape`` (None if absent). Our own reader
    rather than scipy.io.loadmat, whose C parser crashes the interpreter on some corrupt files: every
    length here is checked against the bytes present, and a compressed element is inflated to at most
    the size the expected variable needs (no zlib bomb)."""
    if len(data) < 128 or data[126:128] not in (b"IM", b"MI"):
        raise ValueError("not a MATLAB v5 MAT-file (v4 and v7.3/HDF5 files are not read)")
    order = "<" if data[126:128] == b"IM" else ">"
    need = 8 * int(np.prod(shape)) + 4096
    for kind, payload in _mat_elements(data[128:], order):
        if kind == _MI_COMPRESSED:
            # The variable's name first, from the first bytes inflated, so another (maybe large) variable is
            # skipped without inflating it; ours is inflated to at most the bytes it needs.
            if _matrix_name(zlib.decompressobj().decompress(payload, 512), order) != name:
                continue
            found = list(_mat_elements(zlib.decompressobj().decompress(payload, need), order))
            if not found:
                continue
            kind, payload = found[0]
        if kind != _MI_MATRIX:
            continue
        parts = list(_mat_elements(payload, order))
        if len(parts) < 4 or parts[0][0] != 6 or parts[1][0] != 5 or parts[2][0] not in (1, 2):
            raise ValueError("a matrix element without array flags, dimensions and a name")
        if bytes(parts[2][1]).decode("latin-1") != name:
            continue
        flags = struct.unpack_from(order + "I", parts[0][1])[0]
        dims = tuple(int(d) for d in np.frombuffer(parts[1][1], order + "i4"))
        if flags & 0x800:
            raise ValueError(f"{name} is complex")
        if dims != tuple(shape):
            raise ValueError(f"{name} has shape {dims}, expected {tuple(shape)}")
        kind, real = parts[3]
        if kind not in _MAT_TYPES or len(real) != int(np.prod(dims)) * np.dtype(_MAT_TYPES[kind]).itemsize:
            raise ValueError(f"{name}'s data (type {kind}, {len(real)} bytes) does not fill {dims}")
        return np.frombuffer(real, order + _MAT_TYPES[kind]).reshape(dims, order="F").astype(np.float64)
    return None


def _read_normals(folder: Path, size: tuple[int, int]) -> np.ndarray | None:
    """Normal_gt.mat's 'Normal_gt' [H, W, 3] float32, or None without the file."""
    gt_path = folder / "Normal_gt.mat"
    if not gt_path.is_file():
        return None
    try:
        normals = _mat_variable(gt_path.read_bytes(), "Normal_gt", (*size, 3))
    except (ValueError, struct.error, zlib.error) as err:
        raise ImageFormatError(f"{gt_path}: not a readable MAT-file Normal_gt ({type(err).__name__}: {err})") from None
    if normals is None:
        raise ImageFormatError(f"{gt_path}: no 'Normal_gt' variable")
    # Unit vectors (zero outside the object); the benchmark's files are unit to 2e-7.
    length = np.linalg.norm(np.nan_to_num(np.clip(normals, -2.0, 2.0), nan=2.0), axis=-1)
    if not np.all(np.isfinite(normals)) or np.any((length > 1e-6) & (np.abs(length - 1) > 1e-3)):
        raise ImageFormatError(f"{gt_path}: Normal_gt must hold finite unit vectors (or zeros outside the object)")
    return normals.astype(np.float32)


def read_diligent(folder: str | os.PathLike, lights: slice | list[int] | None = None) -> DiligentData:
    """Read a DiLiGenT-style folder (see the module docstring).

    Args:
        folder: the object's folder (e.g. ``.../ballPNG``).
        lights: optional subset of lights (indices or a slice) to load.

    Raises (each naming the file): a light count in the text files that does
    not match the images, non-unit light directions, non-positive intensities,
    images that are not 16-bit RGB of one size, a mask of another size.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such DiLiGenT folder")
    names = _light_names(folder)
    dirs, ints = _read_lights(folder, len(names))
    index = np.atleast_1d(np.arange(len(names))[lights] if lights is not None else np.arange(len(names)))
    images = _read_images(folder, names, index)
    size = images.shape[1:3]
    mask = _read_mask(folder, size)
    normals = _read_normals(folder, size)
    check_radiance(images, folder, "DiLiGenT images")
    return DiligentData(
        images=images,
        light_directions=dirs[index].astype(np.float32),
        light_intensities=ints[index].astype(np.float32),
        mask=mask,
        normals_gt=normals,
        filenames=tuple(names[i] for i in index),
    )


def diligent_capture(data: DiligentData, lights=None, saturation: float = 0.995):
    """A DiLiGenT capture as (``stage.Capture``, ``stage.Surface``) for
    ``relight.fit``: one orthographic view down -z, a distant rig with the
    calibrated directions and RGB intensities, one sample per mask pixel (unit
    area, position (column, -row, 0) in pixels, shading frame = the camera's, so
    a fitted normal is in the benchmark's camera frame). ``lights``: indices to
    keep (default all). Observations are valid where the pixel is in the mask,
    the light is above the camera-facing plane and no channel is saturated
    (>= ``saturation`` of the 16-bit range)."""
    import jax.numpy as jnp

    idx = np.arange(len(data.filenames)) if lights is None else np.asarray(lights)
    rows, cols = np.nonzero(data.mask)
    P = len(rows)
    if P == 0:
        raise ValueError("diligent_capture: the mask selects no pixels")
    rig = stage.make_rig(data.light_directions[idx], data.light_intensities[idx], near_field=False)
    h, w = data.mask.shape
    cam = stage.orthographic((0.0, 0.0, 1000.0), extent_mm=float(h), width=w, height=h)
    img = data.images[idx][:, rows, cols, :]  # [L, P, 3]
    valid = np.all(img < saturation, axis=-1) & (data.light_directions[idx, 2] > 0)[:, None]
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    ones = np.ones(P)
    zero = np.zeros(P)
    surface = stage.Surface(
        position=f32(np.stack([cols - w / 2, h / 2 - rows, zero], 1)),
        normal=f32(np.stack([zero, zero, ones], 1)), tangent=f32(np.stack([ones, zero, zero], 1)),
        bitangent=f32(np.stack([zero, ones, zero], 1)),
        uv=f32(np.stack([(cols + 0.5) / w, 1 - (rows + 0.5) / h], 1)), area=f32(ones),
        texel_index=jnp.asarray(rows * w + cols, jnp.int32), face=jnp.zeros(P, jnp.int32), resolution=(h, w))
    capture = stage.Capture(f32(img[None]), jnp.asarray(valid[None]), rig, (cam,))
    return capture, surface

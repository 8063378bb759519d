"""Real multi-light captures laid out like DiLiGenT (Shi et al., CVPR 2016 /
TPAMI 2019, "A Benchmark Dataset and Evaluation for Non-Lambertian and
Uncalibrated Photometric Stereo"):

    folder/001.png ... (16-bit RGB, one per light; order from filenames.txt if present)
    folder/light_directions.txt   L x 3 unit vectors, camera frame
    folder/light_intensities.txt  L x 3 RGB intensities
    folder/mask.png               object mask (pixels equal to the mask's maximum)
    folder/Normal_gt.mat          optional, key 'Normal_gt', H x W x 3

The camera frame is x right, y up, z toward the camera, i.e. the light
stage's frame with the camera on +z.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np

import stage

from ._errors import ImageFormatError, check_radiance
from ._png import read_png

__all__ = ["DiligentData", "diligent_capture", "is_diligent_folder", "lambert_normals", "read_diligent"]


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


def lambert_normals(data: DiligentData) -> np.ndarray:
    """The benchmark's baseline: grey Lambertian least squares on every light,
    float64 [P, 3] per mask pixel (albedo-scaled, not unit length)."""
    img = data.images / data.light_intensities[:, None, None, :]
    grey = np.minimum(0.2989 * img[..., 0] + 0.5870 * img[..., 1] + 0.1140 * img[..., 2], 1.0)
    return np.linalg.lstsq(data.light_directions.astype(np.float64), grey[:, data.mask], rcond=None)[0].T


def _light_names(folder: Path) -> list[str]:
    """The light images in light order: filenames.txt if present, else the numbered PNGs sorted."""
    names_file = folder / "filenames.txt"
    if names_file.is_file():
        names = [ln.strip() for ln in names_file.read_text().splitlines() if ln.strip()]
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


def _read_normals(folder: Path, size: tuple[int, int]) -> np.ndarray | None:
    """Normal_gt.mat's 'Normal_gt' [H, W, 3] float32, or None without the file."""
    gt_path = folder / "Normal_gt.mat"
    if not gt_path.is_file():
        return None
    from scipy.io import loadmat

    mat = loadmat(gt_path)
    if "Normal_gt" not in mat:
        found = sorted(k for k in mat if not k.startswith("__"))
        raise ImageFormatError(f"{gt_path}: no 'Normal_gt' variable (found {found})")
    normals = np.asarray(mat["Normal_gt"], np.float32)
    if normals.shape != (*size, 3):
        raise ImageFormatError(f"{gt_path}: Normal_gt has shape {normals.shape}, expected {(*size, 3)}")
    return normals


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

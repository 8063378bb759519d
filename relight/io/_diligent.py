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

from ._errors import ImageFormatError, check_radiance
from ._png import read_png

__all__ = ["DiligentData", "diligent_capture", "read_diligent"]


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


def _read_table(path: Path, what: str) -> np.ndarray:
    if not path.is_file():
        raise FileNotFoundError(f"{path}: {what} file not found")
    try:
        arr = np.loadtxt(path, dtype=np.float64, ndmin=2)
    except ValueError as err:
        raise ImageFormatError(f"{path}: cannot parse {what} ({err})") from None
    if arr.shape[1] != 3:
        raise ImageFormatError(f"{path}: {what} must have 3 columns, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise ImageFormatError(f"{path}: {what} contains NaN/Inf")
    return arr


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
    names_file = folder / "filenames.txt"
    if names_file.is_file():
        names = [ln.strip() for ln in names_file.read_text().splitlines() if ln.strip()]
    else:
        names = sorted(p.name for p in folder.glob("*.png") if p.stem.isdigit())
    if not names:
        raise ImageFormatError(f"{folder}: no light images (expected 001.png, 002.png, ... or filenames.txt)")
    dirs = _read_table(folder / "light_directions.txt", "light directions")
    ints = _read_table(folder / "light_intensities.txt", "light intensities")
    for path, arr in ((folder / "light_directions.txt", dirs), (folder / "light_intensities.txt", ints)):
        if arr.shape[0] != len(names):
            raise ImageFormatError(
                f"{path}: {arr.shape[0]} lights listed but {len(names)} images found in {folder}"
            )
    norms = np.linalg.norm(dirs, axis=1)
    if np.any(np.abs(norms - 1) > 1e-3):  # the files carry 4 decimals
        bad = int(np.argmax(np.abs(norms - 1)))
        raise ImageFormatError(
            f"{folder / 'light_directions.txt'}: line {bad + 1} is not a unit vector (length {norms[bad]:.4f})"
        )
    if np.any(ints <= 0):
        raise ImageFormatError(f"{folder / 'light_intensities.txt'}: intensities must be positive")
    index = np.arange(len(names))[lights] if lights is not None else np.arange(len(names))
    index = np.atleast_1d(index)
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
    mask_path = folder / "mask.png"
    if mask_path.is_file():
        m = read_png(mask_path)
        m = m.max(axis=-1) if m.ndim == 3 else m
        if m.shape != images.shape[1:3]:
            raise ImageFormatError(f"{mask_path}: mask size {m.shape} differs from image size {images.shape[1:3]}")
        mask = m == m.max() if m.max() > 0 else np.zeros(m.shape, bool)
    else:
        mask = np.ones(images.shape[1:3], bool)
    normals = None
    gt_path = folder / "Normal_gt.mat"
    if gt_path.is_file():
        from scipy.io import loadmat

        mat = loadmat(gt_path)
        if "Normal_gt" not in mat:
            found = sorted(k for k in mat if not k.startswith("__"))
            raise ImageFormatError(f"{gt_path}: no 'Normal_gt' variable (found {found})")
        normals = np.asarray(mat["Normal_gt"], np.float32)
        if normals.shape != (*images.shape[1:3], 3):
            raise ImageFormatError(f"{gt_path}: Normal_gt has shape {normals.shape}, "
                                   f"expected {(*images.shape[1:3], 3)}")
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

    import stage

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

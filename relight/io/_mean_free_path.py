"""Mean-free-path maps: an EXR of the diffuse mean free path (mm) read, checked and looked up at surface samples."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

import stage

from ..image import sample_texture
from ._errors import existing_file
from ._exr import read_exr


def read_mean_free_path(path: str | os.PathLike) -> np.ndarray:
    """The diffuse mean free path map of an EXR file, in mm.

    Args:
        path: an EXR with 3 channels (R, G, B) or 1 (Y, used for all three), values in mm (>= 0;
            0 = no subsurface scattering there).

    Returns:
        float64 [H, W, 3].

    Raises:
        FileNotFoundError: when ``path`` is not a file.
        ValueError: naming the file, for an unreadable EXR, another channel count, NaN, Inf or
            negative values.
    """
    path = Path(path)
    existing_file(path, "mean-free-path EXR")
    mfp = np.asarray(read_exr(path), np.float64)
    if mfp.ndim == 2:
        mfp = mfp[..., None]
    if mfp.shape[-1] not in (1, 3):
        raise ValueError(f"{path}: a mean free path map has 3 channels (R, G, B) or 1 (Y), this one "
                         f"{mfp.shape[-1]}")
    if not np.all(np.isfinite(mfp)):
        raise ValueError(f"{path}: the mean free path map has NaN or Inf values")
    if np.any(mfp < 0):
        raise ValueError(f"{path}: the mean free path map has negative values (min {mfp.min():.3g}; mm, >= 0)")
    return np.repeat(mfp, 3, axis=-1) if mfp.shape[-1] == 1 else mfp


def mean_free_path_at(mfp: np.ndarray, surface: stage.Surface) -> np.ndarray:
    """The mean free path at the surface's samples.

    Args:
        mfp: float [3] (one value per channel, everywhere) or a map [H, W, 3] on the texture atlas.
        surface: the P samples.

    Returns:
        float64 [P, 3]: the value per channel, or the map's texel of each sample when the map has the
        surface's grid size (``surface.resolution``), else the map bilinearly sampled at the samples' uv.
    """
    mfp = np.asarray(mfp, np.float64)
    if mfp.shape == (3,):
        return np.broadcast_to(mfp, (surface.num_samples, 3)).copy()
    if mfp.ndim != 3 or mfp.shape[-1] != 3:
        raise ValueError(f"mean_free_path_at: mfp must be [3] or [H, W, 3], got {mfp.shape}")
    if tuple(mfp.shape[:2]) == tuple(surface.resolution):
        return mfp.reshape(-1, 3)[np.asarray(surface.texel_index)]
    return sample_texture(mfp, np.asarray(surface.uv, np.float64))

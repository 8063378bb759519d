"""Preview PNGs of linear images: tone-mapped with the previews' one exposure
rule (``relight.image.subject_exposure``) and, for texel-space maps, enlarged so
that a small texel grid is still visible."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..image import PREVIEW_MIN_PX, subject_exposure, to_uint8, tonemap, upscale_nearest
from ..results import writing
from ._png import write_png

__all__ = ["write_map_previews", "write_preview"]


def write_preview(path: str | os.PathLike, img: np.ndarray, exposure: float | None = None, curve: str = "filmic",
                  min_px: int = 0) -> None:
    """Write a tone-mapped 8-bit sRGB PNG of a linear image, atomically.

    Args:
        path: the PNG to write.
        img: linear radiance [H, W], [H, W, 1] (shown grey), [H, W, 2] (blue 0) or [H, W, 3].
        exposure: stops added before tone mapping; None: ``relight.image.subject_exposure`` (metered on the
            pixels with positive luminance).
        curve: ``relight.image.tonemap``'s curve ("filmic", "none", ...).
        min_px: > 0: the image enlarged nearest-neighbour until its shorter side has at least this many
            pixels (``relight.image.upscale_nearest``, for texel-space maps).

    Returns:
        None. A failed write names ``path`` (a full disk as ``relight.results.NoSpaceError``).
    """
    img = np.asarray(img, np.float32)
    if img.ndim == 2:
        img = img[..., None]
    if img.shape[-1] == 1:
        img = np.repeat(img, 3, -1)
    elif img.shape[-1] == 2:
        img = np.concatenate([img, np.zeros_like(img[..., :1])], -1)
    exposure = subject_exposure(img) if exposure is None else exposure
    png = to_uint8(tonemap(img, exposure=exposure, curve=curve))
    with writing(path):
        write_png(path, upscale_nearest(png, min_px) if min_px > 0 else png)


def write_map_previews(folder: str | os.PathLike, albedo: np.ndarray, specular: np.ndarray,
                       roughness: np.ndarray) -> None:
    """Write albedo.png, specular.png and roughness.png of texel-space maps into a folder.

    Args:
        folder: an existing folder.
        albedo: [H, W, 3], linear, 0-1 shown as it is (no exposure, no curve).
        specular: [H, W, 1].
        roughness: [H, W, 1].

    Returns:
        None. Each image is enlarged to at least ``relight.image.PREVIEW_MIN_PX`` pixels a side.
    """
    for name, img in (("albedo", albedo), ("specular", specular), ("roughness", roughness)):
        write_preview(Path(folder) / f"{name}.png", img, exposure=0.0, curve="none", min_px=PREVIEW_MIN_PX)

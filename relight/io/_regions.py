"""Region labels on a texel grid: a label map (PNG colours or EXR integers) read
at a surface's samples, for the per-region subsurface fit."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ._errors import ImageFormatError, existing_file

# The largest label map read: an 8192^2 texel grid's worth of labels.
MAX_LABEL_PIXELS = 8192 * 8192

def read_regions(path: str | os.PathLike, surface) -> np.ndarray:
    """Region labels 0..R-1 at a surface's samples, read from a label map.

    A PNG's distinct colours are the regions; an EXR's first channel holds integer labels (rounded). The
    map is read at the texel itself when it has the texel grid's size, else at the nearest texel to each
    sample's uv. The image readers check the declared size before decoding (``MAX_IMAGE_PIXELS``).

    Args:
        path: a ``.png`` or ``.exr`` label map.
        surface: a ``stage.Surface`` on a texel grid (``resolution``, ``texel_index``, ``uv``).

    Returns:
        int64 labels [P], renumbered to 0..R-1 over the surface's samples (contiguous, as
        :func:`relight.fit_subsurface`'s ``regions`` takes them).

    Raises:
        FileNotFoundError: no such file. ImageFormatError (a ValueError): another suffix, a corrupt or
        oversized image, NaN or Inf labels; each naming the file.
    """
    from ._exr import read_exr
    from ._png import read_png

    p = Path(path)
    existing_file(p, "label map")
    suffix = p.suffix.lower()
    if suffix == ".png":
        # A label map is sampled by UV at any size, up to the largest texel grid (relight.cli's --resolution
        # limit), checked before any row is decoded.
        img = np.asarray(read_png(p, max_pixels=MAX_LABEL_PIXELS))
        img = img[..., None] if img.ndim == 2 else img
        _, lab = np.unique(img.reshape(-1, img.shape[-1]), axis=0, return_inverse=True)
        lab = lab.reshape(img.shape[:2])
    elif suffix == ".exr":
        ch = np.asarray(read_exr(p), np.float64)[..., 0]
        if not np.all(np.isfinite(ch)):
            raise ImageFormatError(f"{path}: NaN or Inf labels")
        lab = np.rint(ch).astype(np.int64)
    else:
        raise ImageFormatError(f"{path}: a label map is a .png or an .exr")
    H, W = surface.resolution
    if lab.shape == (H, W):
        at = lab.reshape(-1)[np.asarray(surface.texel_index)]
    else:
        uv = np.asarray(surface.uv, np.float64)
        h, w = lab.shape
        x = np.clip(np.floor(uv[:, 0] * w), 0, w - 1).astype(int)
        y = np.clip(np.floor((1 - uv[:, 1]) * h), 0, h - 1).astype(int)
        at = lab[y, x]
    return np.unique(at, return_inverse=True)[1].reshape(-1).astype(np.int64)

"""The coverage picture of a photo capture resampled onto a texel grid."""

from __future__ import annotations

import numpy as np

from ._preview import PREVIEW_MIN_PX, upscale_nearest

# Grey levels of the seen texels: from this level (one camera) up to 255 (the most cameras any texel has).
_SEEN_MIN_LEVEL = 64
_UNSEEN_RGB = (255, 0, 0)


def coverage_image(coverage, min_px: int = PREVIEW_MIN_PX) -> np.ndarray:
    """An 8-bit RGB picture of how many cameras see each texel.

    Black off the atlas (a negative count), red where no camera sees a texel (its maps are the fit's
    flagged defaults), grey levels from dark (one camera) to white (the most cameras of any texel).

    Args:
        coverage: int [H, W], cameras per texel (``relight.io.PhotoTexelReport.coverage``; < 0 off the atlas).
        min_px: the picture is enlarged nearest-neighbour to at least this many pixels a side.

    Returns:
        uint8 [H k, W k, 3] for the smallest whole factor k that reaches ``min_px``.
    """
    cov = np.asarray(coverage)
    n = max(int(cov.max(initial=0)), 1)
    img = np.zeros(cov.shape + (3,), np.uint8)
    seen = cov > 0
    level = np.round(_SEEN_MIN_LEVEL + (255 - _SEEN_MIN_LEVEL) * (cov.clip(0, None) / n)).astype(np.uint8)
    img[seen] = level[seen, None]
    img[cov == 0] = _UNSEEN_RGB
    return upscale_nearest(img, min_px)

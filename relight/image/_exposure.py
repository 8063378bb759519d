"""The one auto-exposure rule of every preview the project writes: from the
subject, never the background.

Photographic metering (Reinhard et al. 2002, "Photographic Tone Reproduction
for Digital Images", sec. 2: the scene's key mapped to a fixed display value)
on a robust statistic: the median Rec. 709 luminance of the pixels the subject
covers is brought to ``SUBJECT_KEY``. The environment seen behind the subject
(a bright sky) and the empty pixels around it do not move the exposure, so an
image-based and a model-based render of the same radiance get the same one.
"""

from __future__ import annotations

import numpy as np
from jaxtyping import ArrayLike

__all__ = ["SUBJECT_KEY", "SUBJECT_PERCENTILE", "luminance", "subject_exposure"]

# Rec. 709 / sRGB primaries' luminance weights (ITU-R BT.709-6, item 3.2).
_REC709 = np.array([0.2126, 0.7152, 0.0722])
# The subject's median is metered: robust to specular glints (a high percentile is not) and to a shadowed
# minority of the subject (a low one is not).
SUBJECT_PERCENTILE = 50.0
# Display value (linear, before the tone curve) the metered luminance is brought to: one stop over the
# photographic middle grey 0.18 (Reinhard 2002's key a), where light skin sits in the Zone System; under
# the filmic curve it shows at ~0.73 sRGB. The demo's hand-set value before this rule, kept.
SUBJECT_KEY = 0.35
# A pixel belongs to the subject when at least this fraction of it is covered (half its sub-pixel rays hit).
_MIN_COVERAGE = 0.5
# Luminance below this is no signal (an all-black subject): exposure 0 rather than a huge gain.
_TINY = 1e-12


def luminance(image: ArrayLike) -> np.ndarray:
    """Luminance of an image: Rec. 709 weights for linear RGB, the channel mean otherwise.

    Args:
        image: the image [..., C] (C = 3: linear RGB; other channel counts: grey or other).

    Returns:
        Luminance [...].

    References:
        ITU-R BT.709 (the luminance coefficients 0.2126, 0.7152, 0.0722).
    """
    img = np.asarray(image, np.float64)
    if img.ndim < 1:
        raise ValueError(f"image must have a channel axis [..., C], got shape {img.shape}")
    if img.shape[-1] == 3:
        return img @ _REC709
    return img.mean(axis=-1)


def subject_exposure(image: ArrayLike, coverage: ArrayLike | None = None, percentile: float = SUBJECT_PERCENTILE,
                     key: float = SUBJECT_KEY) -> float:
    """Exposure in stops (``relight.image.tonemap``'s ``exposure``: radiance x 2^stops) that brings the
    ``percentile``-th percentile of the subject's luminance to ``key``.

    Args:
        image: radiance [..., H, W, C] (any leading axes: frames, cameras; one exposure for all, so they
            compare), linear, in the environment's units.
        coverage: [..., H, W] fraction of each pixel the subject covers (a render's alpha; a texel map's
            coverage), broadcastable to ``image[..., 0]``; pixels with coverage >= 0.5 are the subject,
            their luminance taken unpremultiplied (divided by the coverage). None: the pixels with positive
            luminance are the subject (an image without a coverage, e.g. a texel-space preview).
        percentile: in [0, 100]; default the median.
        key: positive target value.

    Returns:
        float stops; 0.0 when there is no subject or its luminance is 0 (nothing to meter).
    """
    if not 0.0 <= float(percentile) <= 100.0:
        raise ValueError(f"percentile must be in [0, 100], got {percentile!r}")
    if not (np.isfinite(key) and key > 0):
        raise ValueError(f"key must be a positive number, got {key!r}")
    lum = luminance(image)
    lum = np.where(np.isfinite(lum), np.maximum(lum, 0.0), 0.0)
    if coverage is None:
        subject = lum[lum > 0]
    else:
        cov = np.asarray(coverage, np.float64)
        try:
            cov = np.broadcast_to(cov, lum.shape)
        except ValueError:
            raise ValueError(f"coverage of shape {cov.shape} does not match the image's pixels "
                             f"{lum.shape}") from None
        inside = cov >= _MIN_COVERAGE
        subject = lum[inside] / cov[inside]
    if subject.size == 0:
        return 0.0
    level = float(np.percentile(subject, percentile))
    return float(np.log2(key / level)) if level > _TINY else 0.0

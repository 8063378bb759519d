"""Tone mapping for previews: exposure, a compressive curve, the sRGB transfer.

All functions are pure ``jax.numpy`` (jit/vmap/grad-safe) except the final
quantisers ``to_uint8`` / ``to_uint16``, which return numpy arrays for writing.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

__all__ = ["srgb_decode", "srgb_encode", "tonemap", "to_uint8", "to_uint16", "CURVES"]

# IEC 61966-2-1 (sRGB): linear segment below this linear value, power law above.
_SRGB_LINEAR_CUTOFF = 0.0031308
_SRGB_ENCODED_CUTOFF = 0.04045  # = 12.92 * 0.0031308, rounded as in the standard

CURVES = ("reinhard", "filmic", "none")


@jax.jit
def srgb_encode(linear: Float[ArrayLike, "*shape"]) -> Float[Array, "*shape"]:
    """Linear [0, 1] -> sRGB-encoded [0, 1] (IEC 61966-2-1 opto-electronic transfer).

    ``12.92 x`` for ``x <= 0.0031308``, else ``1.055 x^(1/2.4) - 0.055``.
    Input is clipped to [0, 1] first (the transfer is only defined there), and
    the power's argument is guarded so the gradient is finite at 0.
    """
    x = jnp.clip(jnp.asarray(linear), 0.0, 1.0)
    hi = x > _SRGB_LINEAR_CUTOFF
    power = 1.055 * jnp.power(jnp.where(hi, x, 1.0), 1.0 / 2.4) - 0.055
    return jnp.where(hi, power, 12.92 * x)


@jax.jit
def srgb_decode(encoded: Float[ArrayLike, "*shape"]) -> Float[Array, "*shape"]:
    """sRGB-encoded [0, 1] -> linear [0, 1] (the inverse of :func:`srgb_encode`).

    ``v / 12.92`` for ``v <= 0.04045``, else ``((v + 0.055) / 1.055)^2.4``.
    """
    v = jnp.clip(jnp.asarray(encoded), 0.0, 1.0)
    hi = v > _SRGB_ENCODED_CUTOFF
    power = jnp.power((jnp.where(hi, v, 1.0) + 0.055) / 1.055, 2.4)
    return jnp.where(hi, power, v / 12.92)


def _aces_narkowicz(x: Array) -> Array:
    """Narkowicz 2015, "ACES Filmic Tone Mapping Curve": a rational fit of the ACES
    reference rendering transform, (x (2.51 x + 0.03)) / (x (2.43 x + 0.59) + 0.14).
    Maps 0 -> 0, is monotone for x >= 0 and reaches 1 at x ~ 11.2 (clipped above)."""
    # The curve is saturated (clipped to 1) long before 64; capping the input
    # keeps x^2 from overflowing to inf/inf = NaN for enormous radiance.
    x = jnp.minimum(x, 64.0)
    return jnp.clip((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0)


@functools.partial(jax.jit, static_argnames=('curve',))
def tonemap(
    radiance: Float[ArrayLike, "*shape"],
    exposure: float | Float[ArrayLike, ""] = 0.0,
    curve: str = "reinhard",
) -> Float[Array, "*shape"]:
    """Radiance -> a displayable sRGB-encoded value in [0, 1].

    ``x = radiance * 2**exposure`` (exposure in stops), then per channel:

    * ``"reinhard"``: ``x / (1 + x)`` (Reinhard et al. 2002, eq. 3), which never
      clips, so a very bright sun still shows as ~1 without a hard edge;
    * ``"filmic"``: the ACES fit of Narkowicz 2015 (toe and shoulder; clips at ~11);
    * ``"none"``: a hard clip at 1;

    followed by the sRGB transfer (:func:`srgb_encode`). Negative and NaN
    radiance (not valid input) map to 0 rather than propagating.
    """
    if curve not in CURVES:
        raise ValueError(f"unknown tone curve {curve!r}; expected one of {CURVES}")
    x = jnp.asarray(radiance)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.float32)
    x = x * jnp.exp2(jnp.asarray(exposure, x.dtype))
    x = jnp.where(x > 0, x, 0.0)  # also maps NaN to 0 (NaN > 0 is False)
    x = jnp.where(jnp.isfinite(x), x, jnp.asarray(jnp.finfo(x.dtype).max, x.dtype))
    if curve == "reinhard":
        y = x / (1.0 + x)
    elif curve == "filmic":
        y = _aces_narkowicz(x)
    else:
        y = jnp.clip(x, 0.0, 1.0)
    return srgb_encode(y)


def to_uint8(image: ArrayLike) -> np.ndarray:
    """A [0, 1] float image as uint8: rounded to nearest, values outside [0, 1] clipped, NaN -> 0.

    Args:
        image: the float image.

    Returns:
        The uint8 image, the same shape.
    """
    x = np.nan_to_num(np.asarray(image, dtype=np.float64), nan=0.0)
    return np.round(np.clip(x, 0.0, 1.0) * 255.0).astype(np.uint8)


def to_uint16(image: ArrayLike) -> np.ndarray:
    """A [0, 1] float image as uint16: rounded to nearest, values outside [0, 1] clipped, NaN -> 0.

    Args:
        image: the float image.

    Returns:
        The uint16 image, the same shape.
    """
    x = np.nan_to_num(np.asarray(image, dtype=np.float64), nan=0.0)
    return np.round(np.clip(x, 0.0, 1.0) * 65535.0).astype(np.uint16)

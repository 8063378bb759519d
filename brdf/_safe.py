"""Safe numerics: the one place where square roots, divisions, normalisations
and arc-cosines are guarded.

Every function uses the double-``where`` pattern (equinox, pbrt's SafeSqrt):
the unsafe operand is replaced by a harmless value *before* the operation, so
the masked lane yields a finite value and a zero (not NaN) gradient.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

# Smallest squared length treated as a direction. Below it a vector carries no
# usable direction and normalisation returns the fallback (zero vector).
_TINY_SQ = 1e-30


def working_float(x: Array | np.dtype | type) -> np.dtype:
    """The floating dtype a guarded computation on ``x`` (an array, or a dtype)
    runs in: ``x``'s own when it is a float of at least 32 bits and not weakly
    typed, else float32.

    This is what ``jnp.result_type(x, jnp.float32)`` gives under JAX's standard
    promotion (half precision, integers and weakly typed Python scalars are
    computed in float32), written out so that it also holds under
    ``jax_numpy_dtype_promotion="strict"``, where that query raises for float64.
    """
    if isinstance(x, (np.dtype, type)):
        dtype, weak = np.dtype(x), False
    else:
        dtype, weak = np.dtype(x.dtype), bool(x.weak_type)
    if not weak and jnp.issubdtype(dtype, jnp.floating) and jnp.finfo(dtype).bits >= 32:
        return dtype
    return np.dtype(jnp.float32)


def widest_float(*xs) -> np.dtype:
    """The one floating dtype that ``xs`` (arrays, Python scalars or dtypes) are
    computed in: the widest strongly typed floating one; weakly typed values
    (Python scalars) and non-floating ones do not widen it; the default float
    when none is left.

    What ``jnp.result_type`` gives for floats under JAX's standard promotion,
    chosen by width so that it also holds under
    ``jax_numpy_dtype_promotion="strict"`` (which refuses the float32-with-
    float64 query itself); callers then cast each operand with ``astype``.
    """
    strong = []
    for x in xs:
        if isinstance(x, (np.dtype, type, str)):
            d, weak = np.dtype(x), False
        elif hasattr(x, "dtype"):
            d, weak = np.dtype(x.dtype), bool(getattr(x, "weak_type", False))
        else:
            continue  # a Python scalar: weakly typed
        if not weak and jnp.issubdtype(d, jnp.floating):
            strong.append(d)
    if not strong:
        return np.dtype(jnp.result_type(float))
    return max(strong, key=lambda d: jnp.finfo(d).bits)


def safe_sqrt(x: ArrayLike) -> Array:
    """sqrt(max(x, 0)) with a finite gradient at and below 0 (gradient 0 there)."""
    x = jnp.asarray(x)
    ok = x > 0
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, x, 1)), 0)


def safe_div(num: ArrayLike, den: ArrayLike, fallback: ArrayLike = 0.0) -> Array:
    """num / den, returning ``fallback`` (and gradient 0) where den == 0."""
    num = jnp.asarray(num)
    den = jnp.asarray(den)
    ok = den != 0
    return jnp.where(ok, num / jnp.where(ok, den, 1), fallback)


def dot(a: Float[Array, "*batch 3"], b: Float[Array, "*batch 3"]) -> Float[Array, "*batch 1"]:
    """Dot product over the last axis (length 3), keeping it as length 1.

    Written as three products rather than ``jnp.sum``: XLA's CPU backend turns a
    reduction into its own fusion, which splits an otherwise elementwise kernel
    into several loops that each go through memory (see docs/brdf.md, Speed).
    """
    return a[..., 0:1] * b[..., 0:1] + a[..., 1:2] * b[..., 1:2] + a[..., 2:3] * b[..., 2:3]


def safe_normalize(v: Float[Array, "*batch d"]) -> Float[Array, "*batch d"]:
    """v / |v| along the last axis; the zero vector (finite gradient) where |v| ~ 0."""
    v = jnp.asarray(v)
    # 3-vectors (directions) avoid the reduction, see dot(); other lengths sum
    sq = dot(v, v) if v.shape[-1] == 3 else jnp.sum(v * v, axis=-1, keepdims=True)
    ok = sq > _TINY_SQ
    inv = jnp.where(ok, 1 / jnp.sqrt(jnp.where(ok, sq, 1)), 0)
    return v * inv


def safe_acos(x: ArrayLike) -> Array:
    """arccos(clip(x, -1, 1)) with finite gradients at |x| = 1.

    The derivative of arccos is infinite at +-1; the clip is applied strictly
    inside the domain so the gradient there is the (large but finite) value at
    1 - eps instead of Inf.
    """
    x = jnp.asarray(x)
    dtype = working_float(x)
    eps = jnp.finfo(dtype).eps
    return jnp.arccos(jnp.clip(x.astype(dtype), -1 + eps, 1 - eps))


def safe_log(x: ArrayLike, floor: float = 1e-30) -> Array:
    """log(max(x, floor)) with gradient 0 below the floor."""
    x = jnp.asarray(x)
    ok = x > floor
    return jnp.where(ok, jnp.log(jnp.where(ok, x, 1)), jnp.log(jnp.asarray(floor, x.dtype)))


def safe_pow(x: ArrayLike, p: ArrayLike) -> Array:
    """max(x, 0) ** p, 0 where x <= 0, with finite gradients in x and p there.

    ``jnp.power(0, p)`` has the gradient ``0**p * log(0)`` = NaN in p; here the
    masked lane computes exp(p * log(1)) and its gradient is 0.
    """
    x = jnp.asarray(x)
    ok = x > 0
    return jnp.where(ok, jnp.exp(p * jnp.log(jnp.where(ok, x, 1))), 0)


def safe_atan2(y: ArrayLike, x: ArrayLike) -> Array:
    """atan2(y, x), 0 (gradient 0) at the origin where the angle is undefined."""
    y = jnp.asarray(y)
    x = jnp.asarray(x)
    ok = (x != 0) | (y != 0)
    return jnp.where(ok, jnp.arctan2(jnp.where(ok, y, 0), jnp.where(ok, x, 1)), 0)

"""Safe numerics: the one place where square roots, divisions, normalisations
and arc-cosines are guarded.

Every function uses the double-``where`` pattern (equinox, pbrt's SafeSqrt):
the unsafe operand is replaced by a harmless value *before* the operation, so
the masked lane yields a finite value and a zero (not NaN) gradient.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

# Smallest squared length treated as a direction. Below it a vector carries no
# usable direction and normalisation returns the fallback (zero vector).
_TINY_SQ = 1e-30


def working_float(x: Array | np.dtype | type) -> np.dtype:
    """The floating dtype a guarded computation on ``x`` runs in: ``x``'s own float of >= 32 bits, else float32.

    This is what ``jnp.result_type(x, jnp.float32)`` gives under JAX's standard promotion (half precision,
    integers and weakly typed Python scalars are computed in float32), written out so that it also holds under
    ``jax_numpy_dtype_promotion="strict"``, where that query raises for float64.

    Args:
        x: an array, or a dtype; a weakly typed value counts as no float.

    Returns:
        The dtype.
    """
    if isinstance(x, (np.dtype, type)):
        dtype, weak = np.dtype(x), False
    else:
        dtype, weak = np.dtype(x.dtype), bool(x.weak_type)
    if not weak and jnp.issubdtype(dtype, jnp.floating) and jnp.finfo(dtype).bits >= 32:
        return dtype
    return np.dtype(jnp.float32)


def widest_float(*xs) -> np.dtype:
    """The one floating dtype that ``xs`` are computed in: the widest strongly typed floating one.

    What ``jnp.result_type`` gives for floats under JAX's standard promotion, chosen by width so that it also holds
    under ``jax_numpy_dtype_promotion="strict"`` (which refuses the float32-with-float64 query itself); callers
    then cast each operand with ``astype``.

    Args:
        *xs: arrays, Python scalars or dtypes; weakly typed values (Python scalars) and non-floating ones do not
            widen the result.

    Returns:
        The dtype; the default float when no strongly typed float is given.
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
    """sqrt(max(x, 0)) with a finite gradient at and below 0 (gradient 0 there).

    Args:
        x: any array.

    Returns:
        The square root, the shape of ``x``.
    """
    x = jnp.asarray(x)
    ok = x > 0
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, x, 1)), 0)


@jax.custom_jvp
def _quotient(num: Array, den: Array) -> Array:
    ok = den != 0
    return jnp.where(ok, num / jnp.where(ok, den, 1), 0)


@_quotient.defjvp
def _quotient_jvp(primals, tangents):
    # d(n/d) = (dn - q dd) / d, written through the quotient q: JAX's own rule for
    # division, -g n d^-2, forms g d^-2 first, which overflows float32 for a ratio of
    # two small numbers (d = 1e-12, g = 1e18: inf, then inf * n with n ~ d) although
    # the derivative itself is ~ g q / d, finite.
    num, den = primals
    d_num, d_den = tangents
    ok = den != 0
    den_s = jnp.where(ok, den, 1)
    q = jnp.where(ok, num / den_s, 0)
    inv = jnp.where(ok, 1 / den_s, 0)
    return q, (d_num - q * d_den) * inv


def _inexact(x: Array, like: Array) -> Array:
    if jnp.issubdtype(x.dtype, jnp.inexact):
        return x
    return x.astype(like.dtype if jnp.issubdtype(like.dtype, jnp.inexact) else jnp.result_type(float))


def safe_div(num: ArrayLike, den: ArrayLike, fallback: ArrayLike = 0.0) -> Array:
    """num / den, returning ``fallback`` (and gradient 0) where den == 0.

    The gradient is (dn - q dd) / den with q = num / den (a custom JVP): finite whenever the quotient and 1/den
    are, also for a ratio of two numbers below 1e-19 in float32, where JAX's rule for division overflows.

    Args:
        num: the numerator.
        den: the denominator.
        fallback: the value where den == 0.

    Returns:
        The quotient, the broadcast shape.
    """
    num = jnp.asarray(num)
    den = jnp.asarray(den)
    num, den = _inexact(num, den), _inexact(den, num)
    return jnp.where(den != 0, _quotient(num, den), fallback)


@jax.custom_jvp
def safe_hypot(x: ArrayLike, y: ArrayLike) -> Array:
    """sqrt(x^2 + y^2) without overflow or underflow in the squares, with a bounded gradient.

    The gradient is (x, y) / hypot, bounded by 1, and 0 at the origin; the plain sqrt(x^2 + y^2) has the
    gradient 0.5 / sqrt(x^2 + y^2) * 2x, whose first factor overflows float32 times a large cotangent when x, y
    are small.

    Args:
        x, y: the legs.

    Returns:
        The hypotenuse, the broadcast shape.
    """
    return jnp.hypot(x, y)


@safe_hypot.defjvp
def _safe_hypot_jvp(primals, tangents):
    x, y = primals
    dx, dy = tangents
    h = jnp.hypot(x, y)
    ok = h > 0
    h_s = jnp.where(ok, h, 1)
    return h, jnp.where(ok, x / h_s, 0) * dx + jnp.where(ok, y / h_s, 0) * dy


def dot(a: Float[Array, "*batch 3"], b: Float[Array, "*batch 3"]) -> Float[Array, "*batch 1"]:
    """Dot product over the last axis (length 3), keeping it as length 1.

    Written as three products rather than ``jnp.sum``: XLA's CPU backend turns a reduction into its own fusion,
    which splits an otherwise elementwise kernel into several loops that each go through memory (docs/brdf.md,
    Speed).

    Args:
        a, b: vectors [*batch, 3].

    Returns:
        a . b, [*batch, 1].
    """
    return a[..., 0:1] * b[..., 0:1] + a[..., 1:2] * b[..., 1:2] + a[..., 2:3] * b[..., 2:3]


def safe_normalize(v: Float[Array, "*batch d"]) -> Float[Array, "*batch d"]:
    """v / |v| along the last axis; the zero vector (finite gradient) where |v| ~ 0.

    Args:
        v: vectors [*batch, d].

    Returns:
        Unit vectors [*batch, d].
    """
    v = jnp.asarray(v)
    # 3-vectors (directions) avoid the reduction, see dot(); other lengths sum
    sq = dot(v, v) if v.shape[-1] == 3 else jnp.sum(v * v, axis=-1, keepdims=True)
    ok = sq > _TINY_SQ
    inv = jnp.where(ok, 1 / jnp.sqrt(jnp.where(ok, sq, 1)), 0)
    return v * inv


def safe_acos(x: ArrayLike) -> Array:
    """arccos(clip(x, -1, 1)) with finite gradients at |x| = 1.

    The derivative of arccos is infinite at +-1; the clip is applied strictly inside the domain so the gradient
    there is the (large but finite) value at 1 - eps instead of Inf.

    Args:
        x: cosines.

    Returns:
        Angles in [0, pi], the shape of ``x``.
    """
    x = jnp.asarray(x)
    dtype = working_float(x)
    eps = jnp.finfo(dtype).eps
    return jnp.arccos(jnp.clip(x.astype(dtype), -1 + eps, 1 - eps))


def safe_log(x: ArrayLike, floor: float = 1e-30) -> Array:
    """log(max(x, floor)) with gradient 0 below the floor.

    Args:
        x: any array.
        floor: the smallest argument taken.

    Returns:
        The logarithm, the shape of ``x``.
    """
    x = jnp.asarray(x)
    ok = x > floor
    return jnp.where(ok, jnp.log(jnp.where(ok, x, 1)), jnp.log(jnp.asarray(floor, x.dtype)))


def safe_pow(x: ArrayLike, p: ArrayLike) -> Array:
    """max(x, 0) ** p, 0 where x <= 0, with finite gradients in x and p there.

    ``jnp.power(0, p)`` has the gradient ``0**p * log(0)`` = NaN in p; here the masked lane computes
    exp(p * log(1)) and its gradient is 0.

    Args:
        x: the base.
        p: the exponent.

    Returns:
        The power, the broadcast shape.
    """
    x = jnp.asarray(x)
    ok = x > 0
    return jnp.where(ok, jnp.exp(p * jnp.log(jnp.where(ok, x, 1))), 0)


@jax.custom_jvp
def _atan2(y: Array, x: Array) -> Array:
    ok = (x != 0) | (y != 0)
    return jnp.where(ok, jnp.arctan2(jnp.where(ok, y, 0), jnp.where(ok, x, 1)), 0)


@_atan2.defjvp
def _atan2_jvp(primals, tangents):
    # d atan2(y, x) = (x dy - y dx) / (x^2 + y^2), evaluated on (x, y) scaled by
    # m = max(|x|, |y|): the squares of components ~1e-20 underflow float32 to 0
    # (inf, then NaN), the scaled ones lie in [1, 2]. Where 1/m is not a normal
    # float (m below the smallest normal number) the gradient is 0.
    y, x = primals
    dy, dx = tangents
    m = jnp.maximum(jnp.abs(x), jnp.abs(y))
    ok = m > jnp.finfo(m.dtype).tiny
    m_s = jnp.where(ok, m, 1)
    xs, ys = x / m_s, y / m_s
    scale = jnp.where(ok, 1 / (m_s * (xs * xs + ys * ys)), 0)
    return _atan2(y, x), (xs * dy - ys * dx) * scale


def safe_atan2(y: ArrayLike, x: ArrayLike) -> Array:
    """atan2(y, x), 0 (gradient 0) at the origin where the angle is undefined.

    The gradient (x dy - y dx) / (x^2 + y^2) is evaluated on (x, y) scaled by their larger magnitude (a custom
    JVP), so it does not underflow near the origin.

    Args:
        y, x: the coordinates.

    Returns:
        The angle in (-pi, pi], the broadcast shape.
    """
    y = jnp.asarray(y)
    x = jnp.asarray(x)
    y, x = _inexact(y, x), _inexact(x, y)
    y, x = jnp.broadcast_arrays(y, x)
    return _atan2(y, x)


# The grazing floor, in ulps of 1. A shading-frame cosine is a dot product of
# unit vectors rounded to the working precision, so its absolute error is a few
# ulps of 1: below 8 ulps (9.5e-7 in float32, 1.8e-15 in float64) even its sign
# is barely known, and the 1/cos and 1/cos^2 factors of Ward, Cook-Torrance,
# V-groove masking, Phong and Oren-Nayar carry only rounding noise. Left alone
# they overflow: f_r ~ 1/(alpha^2 cos^2) at a grazing mirror pair is 8e22 at
# cos = 1e-8, alpha = 1e-4, and its gradient w.r.t. wi ~ 1/(alpha^2 cos^3)
# exceeds float32's 3.4e38 below cos ~ 1e-11; the half vector's 1/|wi + wo| does
# the same to the gradient of every half-vector model when both directions graze.
# Raised to the floor, f_r <= ~1e19 and its gradients <= ~1e29 in float32
# (measured over the NaN sweep's edge pairs).
GRAZING_ULPS = 8


def grazing_floor(dtype) -> float:
    """The smallest cosine (z component) a model evaluates a direction above the horizon at.

    GRAZING_ULPS ulps of 1 in the working float of ``dtype``; see GRAZING_ULPS for the reason.

    Args:
        dtype: the dtype of the directions.

    Returns:
        The floor: 9.5e-7 for float32, 1.8e-15 for float64.
    """
    return GRAZING_ULPS * float(jnp.finfo(working_float(dtype)).eps)


def lift_grazing(w: Float[Array, "*batch 3"]) -> Float[Array, "*batch 3"]:
    """The direction a model evaluates: ``w`` with its z component (cos theta) raised to ``grazing_floor``.

    One elementwise max: exactly ``w`` where cos theta >= the floor, gradient 0 w.r.t. w_z below it. Directions at
    or below the horizon are lifted too, so the lanes a model masks to 0 (it decides which from the cosines before
    the lift) compute finite values and gradients, never 0 * inf = NaN.

    Args:
        w: unit directions [*batch, 3] in the shading frame.

    Returns:
        The lifted directions [*batch, 3].
    """
    w = jnp.asarray(w)
    floor = jnp.asarray([-jnp.inf, -jnp.inf, grazing_floor(w.dtype)], w.dtype)
    return jnp.maximum(w, floor.reshape((1,) * (w.ndim - 1) + (3,)))


def clamp_cos(x: ArrayLike) -> Array:
    """A cosine computed as a dot product of (nominally) unit vectors, clipped to [-1, 1].

    Rounding (or vectors that are not unit length) can take it past 1, and a lobe cos^exponent with exponent up
    to 1e4 then overflows. The gradient is 0 outside [-1, 1].

    Args:
        x: the dot product.

    Returns:
        The clipped cosine, the shape of ``x``.
    """
    x = jnp.asarray(x)
    return jnp.clip(x, -1.0, 1.0)

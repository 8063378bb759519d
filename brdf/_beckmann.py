"""The Beckmann microfacet distribution (Beckmann & Spizzichino 1963; Walter et
al. 2007), anisotropic, with Smith's exact masking.

As in ``_ggx.py``, the physics is in free kernels written once on separate
components (``beckmann_*_xyz(x, y, z, alpha_x, alpha_y)``, for the fitter's
component-major [3, N] arrays: ``beckmann_d_xyz(*wm, ...)``) with last-axis
forms (``beckmann_d(wm, ...)``, wm [*batch, 3] -> [*batch, C]) that
:class:`Beckmann` calls. Roughness is clamped to ALPHA_MIN (gradient 0
below); ``alpha_y`` None means isotropic.
"""

from __future__ import annotations

import jax.numpy as jnp
import jax.scipy.special as jsp
from jaxtyping import Array, ArrayLike, Float

from ._base import ParamSpec
from ._distribution import AbstractMicrofacetDistribution, alpha_specs, clamped_alphas, init_alphas, split
from ._safe import dot, safe_div, safe_log, safe_sqrt

_INV_SQRT_PI = 0.5641895835477563
# Beyond a = cot(theta)/alpha = 30, erfc(a) and exp(-a^2) are 0 even in float64,
# so Lambda is exactly 0: clamping there keeps a^2 finite without changing values.
_A_MAX = 30.0


def _s(x, y, alpha_x, alpha_y):
    # s = alpha-weighted sin(theta) = sqrt(ax^2 x^2 + ay^2 y^2)
    ax, ay = clamped_alphas(alpha_x, alpha_y)
    return safe_sqrt((ax * x) ** 2 + (ay * y) ** 2)


def beckmann_d_xyz(
    x: Float[ArrayLike, "*#shape"],
    y: Float[ArrayLike, "*#shape"],
    z: Float[ArrayLike, "*#shape"],
    alpha_x: Float[ArrayLike, "*#shape"],
    alpha_y: Float[ArrayLike, "*#shape"] | None = None,
) -> Float[Array, "*shape"]:
    """Beckmann density of microfacet normals D(wm), for wm = (x, y, z) given as separate components.

    D(wm) = exp(-((x/ax)^2 + (y/ay)^2) / z^2) / (pi ax ay z^4), normalised so that
    integral D(wm) cos(theta_m) dwm = 1.

    Args:
        x, y, z: components of a unit direction in the shading frame (z = normal); any broadcastable shapes.
        alpha_x, alpha_y: roughness along the tangent and the bitangent (alpha_y None: isotropic, alpha_x);
            clamped to [ALPHA_MIN, 1].

    Returns:
        D in 1/sr, the broadcast shape; 0 for z <= 0.

    References:
        Walter et al. 2007, "Microfacet models for refraction through rough surfaces", eq. 25 (anisotropic form).
    """
    ax, ay = clamped_alphas(alpha_x, alpha_y)
    up = z > 0
    zs = jnp.where(up, z, 1.0)
    # exp(-q/z^2) / z^4 evaluated as one exp: at z ~ 1e-7 the separate factors'
    # gradients are 0 * inf = NaN in float32, the combined exponent's are finite.
    expo = -((x / ax) ** 2 + (y / ay) ** 2) / (zs * zs) - 4.0 * jnp.log(zs)
    return jnp.where(up, jnp.exp(expo) / (jnp.pi * ax * ay), 0.0)


def beckmann_lambda_cos_xyz(
    x: Float[ArrayLike, "*#shape"],
    y: Float[ArrayLike, "*#shape"],
    z: Float[ArrayLike, "*#shape"],
    alpha_x: Float[ArrayLike, "*#shape"],
    alpha_y: Float[ArrayLike, "*#shape"] | None = None,
) -> Float[Array, "*shape"]:
    """cos(theta) Lambda(w) = (s exp(-a^2) / sqrt(pi) - z erfc(a)) / 2 of Beckmann, finite at the horizon.

    s = sqrt((ax x)^2 + (ay y)^2), a = z / s; s / (2 sqrt(pi)) at the horizon.

    Args:
        x, y, z: components of a unit direction in the shading frame (z = normal); any broadcastable shapes.
        alpha_x, alpha_y: roughness along the tangent and the bitangent (alpha_y None: isotropic, alpha_x);
            clamped to [ALPHA_MIN, 1].

    Returns:
        cos(theta) Lambda(w) (unitless), the broadcast shape; 0 for z <= 0.

    References:
        Walter et al. 2007, "Microfacet models for refraction through rough surfaces", sec. 5.1 (the exact
        Smith Lambda), multiplied by cos(theta).
    """
    s = _s(x, y, alpha_x, alpha_y)
    up = z > 0
    zs = jnp.where(up, z, 1.0)
    a = jnp.minimum(safe_div(zs, s, fallback=_A_MAX), _A_MAX)
    v = 0.5 * (s * jnp.exp(-a * a) * _INV_SQRT_PI - zs * jsp.erfc(a))
    return jnp.where(up, jnp.maximum(v, 0.0), 0.0)


def beckmann_lambda_xyz(
    x: Float[ArrayLike, "*#shape"],
    y: Float[ArrayLike, "*#shape"],
    z: Float[ArrayLike, "*#shape"],
    alpha_x: Float[ArrayLike, "*#shape"],
    alpha_y: Float[ArrayLike, "*#shape"] | None = None,
) -> Float[Array, "*shape"]:
    """The exact Smith Lambda(w) of Beckmann, (erf(a) - 1) / 2 + exp(-a^2) / (2 a sqrt(pi)).

    a = |z| / s = 1 / (alpha tan(theta)), s = sqrt((ax x)^2 + (ay y)^2); the exact form, not the paper's rational
    approximation. Depends on |z| (either hemisphere).

    Args:
        x, y, z: components of a unit direction in the shading frame (z = normal); any broadcastable shapes.
        alpha_x, alpha_y: roughness along the tangent and the bitangent (alpha_y None: isotropic, alpha_x);
            clamped to [ALPHA_MIN, 1].

    Returns:
        Lambda >= 0 (unitless), the broadcast shape; at the horizon, where it is infinite, the largest finite
        number of the dtype.

    References:
        Walter et al. 2007, "Microfacet models for refraction through rough surfaces", sec. 5.1.
    """
    s = _s(x, y, alpha_x, alpha_y)
    az = jnp.abs(z)
    a = jnp.minimum(safe_div(az, s, fallback=_A_MAX), _A_MAX)
    big = jnp.finfo(jnp.result_type(s)).max
    # (exp(-a^2)/(a sqrt(pi)) - erfc(a)) / 2, with the 1/a written as s/|z|
    v = 0.5 * (safe_div(s, az, fallback=big) * jnp.exp(-a * a) * _INV_SQRT_PI - jsp.erfc(a))
    return jnp.where(az > 0, jnp.maximum(v, 0.0), big)


def beckmann_g1_xyz(
    x: Float[ArrayLike, "*#shape"],
    y: Float[ArrayLike, "*#shape"],
    z: Float[ArrayLike, "*#shape"],
    alpha_x: Float[ArrayLike, "*#shape"],
    alpha_y: Float[ArrayLike, "*#shape"] | None = None,
) -> Float[Array, "*shape"]:
    """Smith masking G1(w) = 1 / (1 + Lambda(w)) = z / (z + z Lambda) of Beckmann, with the exact Lambda.

    Args:
        x, y, z: components of a unit direction in the shading frame (z = normal); any broadcastable shapes.
        alpha_x, alpha_y: roughness along the tangent and the bitangent (alpha_y None: isotropic, alpha_x);
            clamped to [ALPHA_MIN, 1].

    Returns:
        G1 in [0, 1] (unitless), the broadcast shape; 0 for z <= 0.

    References:
        Walter et al. 2007, "Microfacet models for refraction through rough surfaces", sec. 5.1.
    """
    up = z > 0
    zs = jnp.where(up, z, 1.0)
    return jnp.where(up, zs / (zs + beckmann_lambda_cos_xyz(x, y, z, alpha_x, alpha_y)), 0.0)


def beckmann_g1_over_cos_xyz(
    x: Float[ArrayLike, "*#shape"],
    y: Float[ArrayLike, "*#shape"],
    z: Float[ArrayLike, "*#shape"],
    alpha_x: Float[ArrayLike, "*#shape"],
    alpha_y: Float[ArrayLike, "*#shape"] | None = None,
) -> Float[Array, "*shape"]:
    """G1(w) / cos(theta) = 1 / (z + z Lambda) of Beckmann, finite at the horizon (2 sqrt(pi) / s there).

    Args:
        x, y, z: components of a unit direction in the shading frame (z = normal); any broadcastable shapes.
        alpha_x, alpha_y: roughness along the tangent and the bitangent (alpha_y None: isotropic, alpha_x);
            clamped to [ALPHA_MIN, 1].

    Returns:
        G1 / cos(theta) (unitless), the broadcast shape; 0 for z <= 0.

    References:
        Walter et al. 2007, "Microfacet models for refraction through rough surfaces", sec. 5.1, divided by cos(theta).
    """
    up = z > 0
    zs = jnp.where(up, z, 1.0)
    den = zs + beckmann_lambda_cos_xyz(x, y, z, alpha_x, alpha_y)
    return jnp.where(up, 1.0 / den, 0.0)


def beckmann_d(
    wm: Float[Array, "*batch 3"], alpha_x: ArrayLike, alpha_y: ArrayLike | None = None
) -> Float[Array, "*batch C"]:
    """Beckmann density of microfacet normals D(wm) for last-axis vectors (``beckmann_d_xyz``).

    Args:
        wm: unit directions [*batch, 3] in the shading frame (z = normal).
        alpha_x, alpha_y: roughness along the tangent and the bitangent (alpha_y None: isotropic), broadcast
            against [*batch, C]; clamped to [ALPHA_MIN, 1].

    Returns:
        D in 1/sr, [*batch, C]; 0 for wm_z <= 0.

    References:
        Walter et al. 2007, "Microfacet models for refraction through rough surfaces", eq. 25.
    """
    return beckmann_d_xyz(*split(wm), alpha_x, alpha_y)


def beckmann_lambda(
    w: Float[Array, "*batch 3"], alpha_x: ArrayLike, alpha_y: ArrayLike | None = None
) -> Float[Array, "*batch C"]:
    """The exact Smith Lambda(w) of Beckmann for last-axis vectors (``beckmann_lambda_xyz``).

    Args:
        w: unit directions [*batch, 3] in the shading frame (z = normal).
        alpha_x, alpha_y: roughness along the tangent and the bitangent (alpha_y None: isotropic), broadcast
            against [*batch, C]; clamped to [ALPHA_MIN, 1].

    Returns:
        Lambda >= 0, [*batch, C]; the dtype's largest finite number at the horizon.

    References:
        Walter et al. 2007, "Microfacet models for refraction through rough surfaces", sec. 5.1.
    """
    return beckmann_lambda_xyz(*split(w), alpha_x, alpha_y)


def beckmann_lambda_cos(
    w: Float[Array, "*batch 3"], alpha_x: ArrayLike, alpha_y: ArrayLike | None = None
) -> Float[Array, "*batch C"]:
    """cos(theta) Lambda(w) of Beckmann for last-axis vectors (``beckmann_lambda_cos_xyz``).

    Args:
        w: unit directions [*batch, 3] in the shading frame (z = normal).
        alpha_x, alpha_y: roughness along the tangent and the bitangent (alpha_y None: isotropic), broadcast
            against [*batch, C]; clamped to [ALPHA_MIN, 1].

    Returns:
        cos(theta) Lambda(w), [*batch, C]; 0 below the horizon.

    References:
        Walter et al. 2007, "Microfacet models for refraction through rough surfaces", sec. 5.1, multiplied by
        cos(theta).
    """
    return beckmann_lambda_cos_xyz(*split(w), alpha_x, alpha_y)


def beckmann_g1(
    w: Float[Array, "*batch 3"], alpha_x: ArrayLike, alpha_y: ArrayLike | None = None
) -> Float[Array, "*batch C"]:
    """Smith masking G1(w) = 1 / (1 + Lambda(w)) of Beckmann for last-axis vectors (``beckmann_g1_xyz``).

    Args:
        w: unit directions [*batch, 3] in the shading frame (z = normal).
        alpha_x, alpha_y: roughness along the tangent and the bitangent (alpha_y None: isotropic), broadcast
            against [*batch, C]; clamped to [ALPHA_MIN, 1].

    Returns:
        G1 in [0, 1], [*batch, C]; 0 below the horizon.

    References:
        Walter et al. 2007, "Microfacet models for refraction through rough surfaces", sec. 5.1.
    """
    return beckmann_g1_xyz(*split(w), alpha_x, alpha_y)


def beckmann_g1_over_cos(
    w: Float[Array, "*batch 3"], alpha_x: ArrayLike, alpha_y: ArrayLike | None = None
) -> Float[Array, "*batch C"]:
    """G1(w) / cos(theta) of Beckmann for last-axis vectors (``beckmann_g1_over_cos_xyz``).

    Args:
        w: unit directions [*batch, 3] in the shading frame (z = normal).
        alpha_x, alpha_y: roughness along the tangent and the bitangent (alpha_y None: isotropic), broadcast
            against [*batch, C]; clamped to [ALPHA_MIN, 1].

    Returns:
        G1 / cos(theta), [*batch, C]; 0 below the horizon.

    References:
        Walter et al. 2007, "Microfacet models for refraction through rough surfaces", sec. 5.1, divided by cos(theta).
    """
    return beckmann_g1_over_cos_xyz(*split(w), alpha_x, alpha_y)


class Beckmann(AbstractMicrofacetDistribution):
    """Beckmann distribution of microfacet normals, Gaussian in slope space:

    D(wm) = exp(-((x/ax)^2 + (y/ay)^2) / z^2) / (pi ax ay z^4)  for unit wm
    (Walter et al. 2007, eq. 25, anisotropic form). ``alpha_x``, ``alpha_y`` are the
    RMS slopes times sqrt(2) (unitless, >= 0, clamped to ALPHA_MIN in evaluation);
    isotropic when ``alpha_y`` is None. Smith masking uses the exact
    Lambda(a) = (erf(a) - 1)/2 + exp(-a^2)/(2 a sqrt(pi)), a = 1/(alpha tan(theta))
    (Walter et al. 2007, §5.1, the exact form before its rational approximation).
    """

    alpha_x: Float[Array, "*batch C"]
    alpha_y: Float[Array, "*batch C"] | None

    def __init__(self, alpha_x: ArrayLike, alpha_y: ArrayLike | None = None):
        self.alpha_x, self.alpha_y = init_alphas("Beckmann", alpha_x, alpha_y)

    def D(self, wm: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """Beckmann density in 1/sr (Walter et al. 2007, eq. 25); 0 for wm_z <= 0. See :func:`beckmann_d`."""
        return beckmann_d(wm, self.alpha_x, self.alpha_y)

    def lambda_cos(self, w: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """cos(theta) Lambda(w), finite at the horizon; 0 below it. See :func:`beckmann_lambda_cos`."""
        return beckmann_lambda_cos(w, self.alpha_x, self.alpha_y)

    def Lambda(self, w: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """Exact Smith Lambda; a very large finite value at the horizon. See :func:`beckmann_lambda`."""
        return beckmann_lambda(w, self.alpha_x, self.alpha_y)

    def G1(self, w: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """Smith masking 1 / (1 + Lambda); 0 below the horizon. See :func:`beckmann_g1`."""
        return beckmann_g1(w, self.alpha_x, self.alpha_y)

    def g1_over_cos(self, w: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """G1(w)/cos(theta) = 1 / (z + z Lambda). See :func:`beckmann_g1_over_cos`."""
        return beckmann_g1_over_cos(w, self.alpha_x, self.alpha_y)

    def sample_wm(self, wo: Float[Array, "*batch 3"], u: Float[Array, "*batch 2"]) -> Float[Array, "*batch 3"]:
        """A normal with density D(wm) cos(theta_m) (Walter et al. 2007, eqs. 28-29;
        anisotropic: the slope (ax sx, ay sy) with (sx, sy) standard normal / sqrt(2)).
        ``wo`` is unused: this is not visible-normal sampling."""
        ax, ay = clamped_alphas(self.alpha_x, self.alpha_y)
        # Slope-space Gaussian by Box-Muller: tan^2 = -log(1 - u0) in units of alpha.
        r = safe_sqrt(-safe_log(1.0 - u[..., 0:1]))
        phi = 2.0 * jnp.pi * u[..., 1:2]
        sx = ax * r * jnp.cos(phi)
        sy = ay * r * jnp.sin(phi)
        one = jnp.ones_like(sx * sy)
        m = jnp.concatenate(jnp.broadcast_arrays(-sx, -sy, one), axis=-1)
        return m / jnp.sqrt(dot(m, m))

    def pdf_wm(self, wo: Float[Array, "*batch 3"], wm: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """D(wm) cos(theta_m), in 1/sr."""
        return self.D(wm) * jnp.maximum(split(wm)[2], 0.0)

    def fittable(self) -> dict[str, ParamSpec]:
        """``alpha_x`` (and ``alpha_y`` when anisotropic) in (ALPHA_MIN, 1), sigmoid."""
        return alpha_specs(self.alpha_y)

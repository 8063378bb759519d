"""The Phong family: classic Phong (not reciprocal), the modified reciprocal
Phong with its energy normalisation (Lewis 1994; Lafortune & Willems 1994), and
Blinn-Phong (half vector)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._base import AbstractBRDF, ParamSpec, as_param, check_directions, check_module_rank, cos_theta
from ._distribution import ALPHA_MIN
from ._safe import clamp_cos, dot, lift_grazing, safe_div, safe_normalize, safe_pow, safe_sqrt

_RHO = ParamSpec(0.0, 1.0, "sigmoid")
# The exponent is a scale parameter (1 and 1000 are both common): exp makes
# equal steps in u equal ratios in the exponent.
_EXPONENT = ParamSpec(0.0, float("inf"), "exp")


def blinn_phong_lobe(
    cos_theta_h: Float[ArrayLike, "*#shape"],
    rho_s: Float[ArrayLike, "*#shape"],
    exponent: Float[ArrayLike, "*#shape"],
    normalized: bool = True,
) -> Float[Array, "*shape"]:
    """The Blinn-Phong specular lobe in 1/sr, rho_s (exponent + 8) / (8 pi) cos(theta_h)^exponent.

    The (exponent + 8) / (8 pi) factor is the usual approximate energy normalisation: the lobe's albedo stays close
    to rho_s. No horizon mask: the caller zeroes below-horizon wi, wo. Elementwise (any layout: [*batch, 1] cosines
    with [*batch, C] parameters, or [N] rows).

    Args:
        cos_theta_h: n . h with h = normalize(wi + wo).
        rho_s: specular albedo.
        exponent: the Phong exponent (>= 0).
        normalized: with the (exponent + 8) / (8 pi) factor; False: rho_s cos(theta_h)^exponent.

    Returns:
        The lobe in 1/sr, the broadcast shape; 0 where cos_theta_h <= 0 (finite gradients there, also in the
        exponent).

    References:
        Blinn 1977, "Models of light reflection for computer synthesized pictures"; the normalisation from
        Akenine-Moller & Haines, Real-Time Rendering, 2nd ed., sec. 7.6.
    """
    lobe = safe_pow(cos_theta_h, exponent)
    if normalized:
        lobe = lobe * (exponent + 8.0) / (8.0 * jnp.pi)
    return rho_s * lobe


def phong_exponent(alpha: Float[ArrayLike, "*shape"]) -> Float[Array, "*shape"]:
    """The Blinn-Phong exponent s = max(2 / alpha^2 - 2, 0) with the same lobe width as microfacet roughness alpha.

    ``alpha`` is clamped to ALPHA_MIN (gradient 0 below), so s <= 2e8 and stays finite in float32. Inverse:
    ``alpha_from_phong_exponent``.

    Args:
        alpha: microfacet roughness.

    Returns:
        The exponent (unitless), the shape of ``alpha``; 0 for alpha >= 1.

    References:
        Walter et al. 2007, "Microfacet models for refraction through rough surfaces", sec. 5.2 (the
        Beckmann-Phong correspondence).
    """
    alpha = jnp.maximum(jnp.asarray(alpha), ALPHA_MIN)
    return jnp.maximum(2.0 / (alpha * alpha) - 2.0, 0.0)


def alpha_from_phong_exponent(exponent: Float[ArrayLike, "*shape"]) -> Float[Array, "*shape"]:
    """The microfacet roughness alpha = sqrt(2 / (exponent + 2)) whose ``phong_exponent`` is ``exponent``.

    The inverse of ``phong_exponent`` for alpha in [ALPHA_MIN, 1], i.e. exponent in [0, 2 / ALPHA_MIN^2 - 2].

    Args:
        exponent: the Phong exponent.

    Returns:
        alpha (unitless), the shape of ``exponent``; 0 (finite gradient) for exponent <= -2.

    References:
        Walter et al. 2007, "Microfacet models for refraction through rough surfaces", sec. 5.2.
    """
    return safe_sqrt(safe_div(2.0, jnp.maximum(jnp.asarray(exponent) + 2.0, 0.0)))


def _mirror(w: Float[Array, "*batch 3"]) -> Float[Array, "*batch 3"]:
    # reflect(w, n) about n = z: the tangential part changes sign
    return jnp.concatenate([-w[..., :2], w[..., 2:]], axis=-1)


def _rv(wi, wo):
    """cos(alpha) = dot(reflect(wi), wo), which is symmetric in wi and wo, clipped
    to [-1, 1] (brdf.clamp_cos: raised to the exponent, a value past 1 overflows)."""
    return clamp_cos(dot(_mirror(wi), wo))


def _init(owner, rho_d, rho_s, exponent):
    return (
        as_param(owner, "rho_d", rho_d, lower=0.0),
        as_param(owner, "rho_s", rho_s, lower=0.0),
        as_param(owner, "exponent", exponent, lower=0.0),
    )


class Phong(AbstractBRDF):
    """Classic Phong (Phong 1975) written as a BRDF:

        f_r = rho_d / pi + rho_s cos(alpha)^exponent / cos(theta_i),

    cos(alpha) = dot(reflect(wi), wo). The classic shading formula adds
    k_s (r.v)^s to the diffuse k_d (n.l); dividing by n.l = cos(theta_i) makes it a
    BRDF (Lewis 1994, "Making shaders more physically plausible"), so k_d = rho_d / pi. NOT reciprocal (the
    1/cos(theta_i) singles out wi) and not energy conserving: its albedo grows
    without bound at grazing incidence. Kept for comparison with legacy data.
    """

    rho_d: Float[Array, "*batch C"]
    rho_s: Float[Array, "*batch C"]
    exponent: Float[Array, "*batch C"]

    def __init__(self, rho_d: ArrayLike, rho_s: ArrayLike, exponent: ArrayLike):
        self.rho_d, self.rho_s, self.exponent = _init("Phong", rho_d, rho_s, exponent)

    def __call__(self, wi: Float[Array, "*batch 3"], wo: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """f_r in 1/sr; 0 below the horizon."""
        wi, wo = check_directions("Phong", wi, wo)
        check_module_rank(self, wi.ndim)
        active = (cos_theta(wi) > 0) & (cos_theta(wo) > 0)
        # cos_i raised to the grazing floor keeps 1/cos_i bounded (brdf._safe.GRAZING_ULPS)
        wi, wo = lift_grazing(wi), lift_grazing(wo)
        f = self.rho_d / jnp.pi + self.rho_s * safe_pow(_rv(wi, wo), self.exponent) / cos_theta(wi)
        return jnp.where(active, f, 0.0)

    def fittable(self) -> dict[str, ParamSpec]:
        """``rho_d``, ``rho_s`` in (0, 1) (sigmoid); ``exponent`` > 0 (exp)."""
        return {"rho_d": _RHO, "rho_s": _RHO, "exponent": _EXPONENT}


class ModifiedPhong(AbstractBRDF):
    """The modified, reciprocal Phong BRDF (Lewis 1994; Lafortune & Willems 1994):

        normalized:    f_r = rho_d / pi + rho_s (exponent + 2) / (2 pi) cos(alpha)^exponent
        unnormalized:  f_r = rho_d / pi + rho_s cos(alpha)^exponent

    cos(alpha) = dot(reflect(wi), wo) (clamped at 0). Reciprocal. The normalised
    form (Lafortune & Willems 1994, CW-TR 197, §3) conserves energy when rho_d + rho_s <= 1:
    the lobe's albedo is rho_s at normal incidence and less elsewhere. The
    unnormalised form does not (its lobe albedo at normal incidence is
    2 pi rho_s / (exponent + 2)).
    """

    rho_d: Float[Array, "*batch C"]
    rho_s: Float[Array, "*batch C"]
    exponent: Float[Array, "*batch C"]
    normalized: bool = eqx.field(static=True)

    def __init__(self, rho_d: ArrayLike, rho_s: ArrayLike, exponent: ArrayLike, normalized: bool = True):
        self.rho_d, self.rho_s, self.exponent = _init("ModifiedPhong", rho_d, rho_s, exponent)
        self.normalized = bool(normalized)

    def __call__(self, wi: Float[Array, "*batch 3"], wo: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """f_r in 1/sr; 0 below the horizon."""
        wi, wo = check_directions("ModifiedPhong", wi, wo)
        check_module_rank(self, wi.ndim)
        active = (cos_theta(wi) > 0) & (cos_theta(wo) > 0)
        wi, wo = lift_grazing(wi), lift_grazing(wo)
        lobe = safe_pow(_rv(wi, wo), self.exponent)
        if self.normalized:
            lobe = lobe * (self.exponent + 2.0) / (2.0 * jnp.pi)
        return jnp.where(active, self.rho_d / jnp.pi + self.rho_s * lobe, 0.0)

    def fittable(self) -> dict[str, ParamSpec]:
        """``rho_d``, ``rho_s`` in (0, 1) (sigmoid); ``exponent`` > 0 (exp)."""
        return {"rho_d": _RHO, "rho_s": _RHO, "exponent": _EXPONENT}


class BlinnPhong(AbstractBRDF):
    """Blinn-Phong (Blinn 1977), the half-vector form:

        normalized:    f_r = rho_d / pi + rho_s (exponent + 8) / (8 pi) cos(theta_h)^exponent
        unnormalized:  f_r = rho_d / pi + rho_s cos(theta_h)^exponent

    wh = normalize(wi + wo). Reciprocal. The (exponent + 8) / (8 pi) factor is the
    usual approximate energy normalisation (Akenine-Moller & Haines, Real-Time
    Rendering, 2nd ed., §7.6): it keeps the lobe's albedo close to rho_s, not
    exactly below it; the unnormalised form does not conserve energy.
    """

    rho_d: Float[Array, "*batch C"]
    rho_s: Float[Array, "*batch C"]
    exponent: Float[Array, "*batch C"]
    normalized: bool = eqx.field(static=True)

    def __init__(self, rho_d: ArrayLike, rho_s: ArrayLike, exponent: ArrayLike, normalized: bool = True):
        self.rho_d, self.rho_s, self.exponent = _init("BlinnPhong", rho_d, rho_s, exponent)
        self.normalized = bool(normalized)

    def __call__(self, wi: Float[Array, "*batch 3"], wo: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """f_r in 1/sr; 0 below the horizon."""
        wi, wo = check_directions("BlinnPhong", wi, wo)
        check_module_rank(self, wi.ndim)
        active = (cos_theta(wi) > 0) & (cos_theta(wo) > 0)
        wi, wo = lift_grazing(wi), lift_grazing(wo)  # the half vector's 1/|wi + wo| bounded
        cos_h = cos_theta(safe_normalize(wi + wo))
        lobe = blinn_phong_lobe(cos_h, self.rho_s, self.exponent, self.normalized)
        return jnp.where(active, self.rho_d / jnp.pi + lobe, 0.0)

    def fittable(self) -> dict[str, ParamSpec]:
        """``rho_d``, ``rho_s`` in (0, 1) (sigmoid); ``exponent`` > 0 (exp)."""
        return {"rho_d": _RHO, "rho_s": _RHO, "exponent": _EXPONENT}

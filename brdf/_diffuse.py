"""Rough and retro-reflective diffuse models: Oren-Nayar 1994 and Burley 2012."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._base import AbstractBRDF, ParamSpec, as_param, check_directions, check_module_rank, cos_theta
from ._safe import dot, lift_grazing, safe_acos, safe_div, safe_normalize, safe_sqrt

VARIANTS = ("qualitative", "full")


class OrenNayar(AbstractBRDF):
    """Oren & Nayar 1994 ("Generalization of Lambert's reflectance model",
    SIGGRAPH 94), a rough surface of Lambertian V-grooves with Gaussian slope
    angles of standard deviation ``sigma`` (radians, >= 0; 0 is Lambert).

    ``"qualitative"`` (the paper's simplified model, eq. 30):
        f_r = albedo/pi (A + B max(0, cos(phi_i - phi_o)) sin(a) tan(b)),
        A = 1 - 0.5 s2/(s2 + 0.33), B = 0.45 s2/(s2 + 0.09), s2 = sigma^2,
        a = max(theta_i, theta_o), b = min(theta_i, theta_o).
    ``"full"`` adds the C3 term and the interreflection term L2 (the paper's
    functional approximation, §4.4; as in Mitsuba 0.5's roughdiffuse):
        f_r = albedo/pi (C1 + cos(dphi) C2 tan(b) + (1 - |cos(dphi)|) C3 tan((a+b)/2))
              + 0.17 albedo^2/pi s2/(s2 + 0.13) (1 - cos(dphi) (2b/pi)^2).

    cos(dphi) sin(a) tan(b) is evaluated as (xi xo + yi yo) / max(cos_i, cos_o),
    which has no singularity at normal incidence. Reciprocal. Neither form
    conserves energy exactly: the qualitative model's albedo exceeds the albedo
    parameter slightly near grazing for small sigma (1.013 at sigma = 0.2,
    cos = 0.05), the full one more (interreflection). The full form goes negative
    in forward scattering near grazing for sigma > ~1 rad; it is clamped at 0.
    """

    albedo: Float[Array, "*batch C"]
    sigma: Float[Array, "*batch C"]
    variant: str = eqx.field(static=True)

    def __init__(self, albedo: ArrayLike, sigma: ArrayLike, variant: str = "qualitative"):
        if variant not in VARIANTS:
            raise ValueError(f"OrenNayar: variant must be one of {VARIANTS}, got {variant!r}")
        self.albedo = as_param("OrenNayar", "albedo", albedo, lower=0.0)
        self.sigma = as_param("OrenNayar", "sigma", sigma, lower=0.0)
        self.variant = variant

    def __call__(self, wi: Float[Array, "*batch 3"], wo: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """f_r in 1/sr; 0 below the horizon."""
        wi, wo = check_directions("OrenNayar", wi, wo)
        check_module_rank(self, wi.ndim)
        active = (cos_theta(wi) > 0) & (cos_theta(wo) > 0)
        # tan(b) ~ 1/cos(b) when both directions graze: the cosines raised to the grazing floor
        wi, wo = lift_grazing(wi), lift_grazing(wo)
        ci, co = cos_theta(wi), cos_theta(wo)
        s2 = self.sigma * self.sigma
        cmax = jnp.maximum(ci, co)  # cos(b)
        dot_xy = wi[..., 0:1] * wo[..., 0:1] + wi[..., 1:2] * wo[..., 1:2]  # sin_i sin_o cos(dphi)
        if self.variant == "qualitative":
            a_ = 1.0 - 0.5 * s2 / (s2 + 0.33)
            b_ = 0.45 * s2 / (s2 + 0.09)
            f = self.albedo / jnp.pi * (a_ + b_ * jnp.maximum(dot_xy, 0.0) / cmax)
            return jnp.where(active, f, 0.0)
        cmin = jnp.minimum(ci, co)  # cos(a)
        alpha = safe_acos(cmin)
        beta = safe_acos(cmax)
        sin_i = safe_sqrt(1.0 - ci * ci)
        sin_o = safe_sqrt(1.0 - co * co)
        cos_dphi = jnp.clip(safe_div(dot_xy, sin_i * sin_o), -1.0, 1.0)
        tan_b = safe_div(safe_sqrt(1.0 - cmax * cmax), cmax)
        c1 = 1.0 - 0.5 * s2 / (s2 + 0.33)
        c2k = 0.45 * s2 / (s2 + 0.09)
        # C2 cos(dphi) tan(b): the sin(a) part via dot_xy, the correction only for cos(dphi) < 0
        t2 = c2k * (dot_xy / cmax - jnp.where(cos_dphi < 0, cos_dphi * (2.0 * beta / jnp.pi) ** 3 * tan_b, 0.0))
        c3 = 0.125 * s2 / (s2 + 0.09) * (4.0 * alpha * beta / jnp.pi**2) ** 2
        t3 = (1.0 - jnp.abs(cos_dphi)) * c3 * jnp.tan(0.5 * (alpha + beta))
        l1 = self.albedo * (c1 + t2 + t3)
        l2 = self.albedo**2 * (0.17 * s2 / (s2 + 0.13)) * (1.0 - cos_dphi * (2.0 * beta / jnp.pi) ** 2)
        # The functional approximation turns negative in forward scattering near
        # grazing for very rough surfaces (sigma > ~1 rad): f_r is clamped at 0 there.
        return jnp.where(active, jnp.maximum(l1 + l2, 0.0) / jnp.pi, 0.0)

    def fittable(self) -> dict[str, ParamSpec]:
        """``albedo`` in (0, 1) and ``sigma`` in (0, pi/2) rad, both sigmoid."""
        return {"albedo": ParamSpec(0.0, 1.0, "sigmoid"), "sigma": ParamSpec(0.0, float(jnp.pi / 2), "sigmoid")}


class BurleyDiffuse(AbstractBRDF):
    """Burley 2012 ("Physically-based shading at Disney", §5.3) diffuse with
    retro-reflection:

        f_r = base_color/pi (1 + (F_D90 - 1)(1 - cos_i)^5)(1 + (F_D90 - 1)(1 - cos_o)^5),
        F_D90 = 0.5 + 2 roughness cos^2(theta_d),  cos(theta_d) = wi.wh.

    ``base_color`` in [0, 1], ``roughness`` in [0, 1]. Reciprocal. Not energy
    conserving: rough surfaces seen at grazing angles reflect more than
    ``base_color`` (the retro-reflection peak), by design.
    """

    base_color: Float[Array, "*batch C"]
    roughness: Float[Array, "*batch C"]

    def __init__(self, base_color: ArrayLike, roughness: ArrayLike):
        self.base_color = as_param("BurleyDiffuse", "base_color", base_color, lower=0.0)
        self.roughness = as_param("BurleyDiffuse", "roughness", roughness, lower=0.0)

    def __call__(self, wi: Float[Array, "*batch 3"], wo: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """f_r in 1/sr; 0 below the horizon."""
        wi, wo = check_directions("BurleyDiffuse", wi, wo)
        check_module_rank(self, wi.ndim)
        ci, co = cos_theta(wi), cos_theta(wo)
        active = (ci > 0) & (co > 0)
        cd = dot(wi, safe_normalize(wi + wo))
        fd90 = 0.5 + 2.0 * self.roughness * cd * cd

        def weight(c):
            m = 1.0 - jnp.clip(c, 0.0, 1.0)
            m2 = m * m
            return 1.0 + (fd90 - 1.0) * (m2 * m2 * m)

        return jnp.where(active, self.base_color / jnp.pi * weight(ci) * weight(co), 0.0)

    def fittable(self) -> dict[str, ParamSpec]:
        """``base_color`` and ``roughness`` in (0, 1), sigmoid."""
        return {"base_color": ParamSpec(0.0, 1.0, "sigmoid"), "roughness": ParamSpec(0.0, 1.0, "sigmoid")}

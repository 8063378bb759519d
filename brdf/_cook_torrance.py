"""The Cook-Torrance 1981/1982 reflectance model, written out in the paper's own
terms (Beckmann distribution, V-groove attenuation, exact complex Fresnel)."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._base import AbstractBRDF, ParamSpec, as_param, check_directions, check_module_rank, cos_theta
from ._distribution import ALPHA_MIN
from ._fresnel import fresnel_complex
from ._safe import dot, lift_grazing, safe_div, safe_normalize


class CookTorrance(AbstractBRDF):
    """Cook & Torrance 1982 ("A reflectance model for computer graphics", ACM TOG
    1(1); SIGGRAPH 1981), specular term:

        f_r = F(wi.wh) D(wh) G / (4 cos_i cos_o)
        D = exp(-tan^2(theta_h) / m^2) / (pi m^2 cos^4(theta_h))        (Beckmann)
        G = min(1, 2 (n.h)(n.o)/(o.h), 2 (n.h)(n.i)/(o.h))            (V-groove)
        F = fresnel_complex(wi.wh, eta_m, kappa_m, eta_a, kappa_a)     (F_s, F_p, a, b)

    The paper writes F D G / (pi cos_i cos_o) with D lacking its 1/pi; we use the
    normalisation under which D cos(theta_h) integrates to 1 (Walter et al. 2007),
    which differs from the paper's by the constant 4/pi. ``m`` is the RMS slope
    (clamped to ALPHA_MIN). Add a diffuse term with ``Sum(Lambert(rho_d), ...)``.
    Equivalent to ``Microfacet(Beckmann(m), ConductorFresnel(...), "v_groove")``.
    Reciprocal; the V-groove term does not bound the albedo by 1 exactly.
    """

    m: Float[Array, "*batch C"]
    eta_m: Float[Array, "*batch C"]
    kappa_m: Float[Array, "*batch C"]
    eta_a: Float[Array, "*batch C"]
    kappa_a: Float[Array, "*batch C"]

    def __init__(self, m: ArrayLike, eta_m: ArrayLike, kappa_m: ArrayLike = 0.0, eta_a: ArrayLike = 1.0,
                 kappa_a: ArrayLike = 0.0):
        self.m = as_param("CookTorrance", "m", m, lower=0.0)
        self.eta_m = as_param("CookTorrance", "eta_m", eta_m, lower=0.0, lower_open=True)
        self.kappa_m = as_param("CookTorrance", "kappa_m", kappa_m, lower=0.0)
        self.eta_a = as_param("CookTorrance", "eta_a", eta_a, lower=0.0, lower_open=True)
        self.kappa_a = as_param("CookTorrance", "kappa_a", kappa_a, lower=0.0)

    def __call__(self, wi: Float[Array, "*batch 3"], wo: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """f_r in 1/sr; 0 below the horizon."""
        wi, wo = check_directions("CookTorrance", wi, wo)
        check_module_rank(self, wi.ndim)
        active = (cos_theta(wi) > 0) & (cos_theta(wo) > 0)
        # G / (cos_i cos_o) grows without bound at a grazing mirror pair: the cosines
        # are raised to the grazing floor (brdf._safe.GRAZING_ULPS)
        wi, wo = lift_grazing(wi), lift_grazing(wo)
        ci, co = cos_theta(wi), cos_theta(wo)
        h = wi + wo
        wh = safe_normalize(h)
        nh = cos_theta(wh)  # n.h >= (ci + co)/2 > 0
        oh = dot(wo, wh)
        m = jnp.maximum(self.m, ALPHA_MIN)
        # tan^2(theta_h) from the unnormalised h, not (1 - nh^2)/nh^2: near the peak
        # that cancels, and one float32 ulp of nh^2 over m^2 = 1e-8 multiplies D by e^12
        # (slopes first, then squared: the partial derivatives stay within float32)
        tx, ty = safe_div(h[..., 0:1], h[..., 2:3]), safe_div(h[..., 1:2], h[..., 2:3])
        tan2 = tx * tx + ty * ty
        # one exp for exp(-tan^2/m^2) / cos^4 = exp(-tan^2/m^2) (1 + tan^2)^2: finite
        # gradients when n.h is small
        d = jnp.exp(-tan2 / (m * m) + 2.0 * jnp.log1p(tan2)) / (jnp.pi * m * m)
        g = jnp.minimum(1.0, safe_div(2.0 * nh * jnp.minimum(co, ci), oh))
        f = fresnel_complex(oh, self.eta_m, self.kappa_m, self.eta_a, self.kappa_a)
        return jnp.where(active, f * d * safe_div(g, 4.0 * ci * co), 0.0)

    def fittable(self) -> dict[str, ParamSpec]:
        """``m`` in (ALPHA_MIN, 1) (sigmoid), ``eta_m`` >= 0.01 and ``kappa_m`` >= 0
        (softplus); the ambient medium is fixed."""
        return {
            "m": ParamSpec(ALPHA_MIN, 1.0, "sigmoid"),
            "eta_m": ParamSpec(0.01, float("inf"), "softplus"),
            "kappa_m": ParamSpec(0.0, float("inf"), "softplus"),
        }

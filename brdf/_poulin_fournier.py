"""Poulin & Fournier's anisotropic reflection from parallel cylinders (1990)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._base import AbstractBRDF, ParamSpec, as_param, check_directions, check_module_rank, cos_theta
from ._safe import clamp_cos, dot, lift_grazing, safe_div, safe_pow, safe_sqrt

# The model's floor on the cylinders' height above the base plane (in cylinder
# radii). At h -> 0 the cap's angular half-width t_max = 2 asin(sqrt(h / 2))
# has an infinite derivative in h, and with spacing 0 the period 2 sin(t_max)
# goes to 0. At 1e-6, t_max = 1.4e-3 rad: the caps are optically flat for
# exponents up to ~1e4 (the lobe's width in t, ~0.5/sqrt(exponent), exceeds
# t_max), the period stays > 2.8e-3 and dt_max/dh = 1/sqrt(2h) ~ 700.
# Below the floor h is clamped (gradient 0). It is not a fitter's prior.
H_MIN = 1e-6

# Gauss-Legendre nodes per panel of the specular integral over the cylinder's
# angle (8 panels, so 8 * N_NODES = 48 evaluations of the lobe per pair).
# Measured against 10x the nodes on 40,000 pairs (half near the mirror
# configuration) for 3 cylinder geometries, relative error where f_r is at least
# 1e-6 of its maximum: <= 7e-8 at exponent 1, 3e-7 at 10, 1.5e-5 at 100, 3.7e-5
# at 1e3 and 2.6e-5 at 1e4; 7e-4 at exponent 0.5 (below 1 the lobe's edge
# behaves like (u0 - u)^exponent, which Gauss-Legendre converges to slowly).
N_NODES = 6

# Panel edges of the specular quadrature, in units of the lobe's local decay
# length around the point nearest its peak (see PoulinFournier.__call__): the
# core within 1.5 lengths, the shoulders to 4, the tail to 10 (where a Gaussian
# is down to e^-50) and the rest of the lit interval, on either side.
_PANEL_EDGES = (-10.0, -4.0, -1.5, 0.0, 1.5, 4.0, 10.0)

_RHO = ParamSpec(0.0, 1.0, "sigmoid")
_EXPONENT = ParamSpec(0.0, float("inf"), "exp")  # a scale parameter, as in Phong
_SPACING = ParamSpec(0.0, float("inf"), "softplus")
_HEIGHT = ParamSpec(H_MIN, 1.0, "sigmoid")


def _asin_edges(x: Array) -> Array:
    """asin(clip(x, -1, 1)), exactly +-pi/2 outside (-1, 1) with gradient 0 there
    (double where: the derivative 1/sqrt(1 - x^2) is never evaluated at |x| = 1)."""
    ok = jnp.abs(x) < 1
    return jnp.where(ok, jnp.arcsin(jnp.where(ok, x, 0.0)), jnp.sign(x) * (jnp.pi / 2))


def _acos_edges(x: Array) -> Array:
    """acos(clip(x, -1, 1)), exactly 0 / pi outside (-1, 1), gradient 0 there."""
    return jnp.pi / 2 - _asin_edges(x)


def _lit_interval(wy, wz, t_max, c, w, d, period):
    """The part of one cylinder cap, and of the base between caps, that is lit
    from (or visible in) direction w, for directions above the horizon.

    The cross-section is the y-z plane; the cap is the unit circle centred at
    (0, c), c = h - 1, above z = 0: normals n(t) = (0, sin t, cos t) for
    t in [-t_max, t_max]; its neighbours are at y = +-period. ``a`` is the angle
    of w's projection from z. For a >= 0 the shadow on the cap's right flank is
    cast by the support point of the right neighbour at angle
    tau = max(a - pi/2, -t_max) (its terminator, or its foot when the terminator
    is below the base plane); a cap point t is lit when
    sin(t - a) < period cos a + sin(tau - a). a < 0 is the mirror image.

    Returns (lo, hi) of the lit cap angles (empty when hi <= lo), the lit length
    of the base and whether that length starts at this cap (a >= 0) or at the
    next one.
    """
    plen = jnp.sqrt(wy * wy + wz * wz)  # > 0: wz > 0 in active lanes
    a = jnp.arctan2(wy, wz)
    sin_b, cos_b = jnp.abs(wy) / plen, wz / plen  # b = |a|
    b = jnp.abs(a)
    tau = jnp.maximum(b - jnp.pi / 2, -t_max)
    e = _asin_edges(period * cos_b + jnp.sin(tau - b))
    pos = a >= 0
    lo = jnp.maximum(-t_max, a - jnp.where(pos, jnp.pi / 2, e))
    hi = jnp.minimum(t_max, a + jnp.where(pos, e, jnp.pi / 2))
    # base [w, period - w]: the neighbour's shadow covers it from the neighbour's
    # foot back to y = period - reach, reach = (c sin b - sin(tau - b)) / cos b
    reach = (c * sin_b - jnp.sin(tau - b)) * plen / wz
    base = jnp.clip(d + w - reach, 0.0, d)
    return a, lo, hi, base, pos


class PoulinFournier(AbstractBRDF):
    """Anisotropic reflection from parallel cylinders (Poulin & Fournier 1990,
    "A Model for Anisotropic Reflection", SIGGRAPH 1990, Computer Graphics
    24(4), 273-282).

    The surface is covered by parallel cylinders of radius 1 whose axes run along
    the local x axis (the tangent), raised ``height`` = h in (0, 1] above a flat
    base plane (h = 1: half cylinders) and separated by gaps of ``spacing`` = d
    >= 0 of flat base (the paper's d and h). Every point of the cylinders and of the base reflects
    with the same micro-BRDF, the normalised modified Phong lobe (Lewis 1994;
    Lafortune & Willems 1994)

        f_mu(n; wi, wo) = rho_d / pi + rho_s (exponent + 2) / (2 pi) max(0, r.wo)^exponent,
        r = reflect(wi, n),

    and the macro BRDF averages it over the part of one period of the
    cross-section that is both lit from wi and visible from wo (self-shadowing
    and masking by the neighbouring cylinders, found exactly in closed form):

        f_r = 1 / (P cos_i cos_o) [ integral_{lit & visible cap} f_mu (n.wi)(n.wo) dt
                                    + f_mu(z) cos_i cos_o |lit & visible base| ],

    with P = 2 sin(t_max) + d the period, t the angle of the cap normal
    n = (0, sin t, cos t) and t_max = acos(1 - h). As in the paper, the
    diffuse part of the cap integral is exact (closed form); the paper integrates a
    Chebyshev fit of the specular term, here the specular integral uses
    ``N_NODES``-point Gauss-Legendre on 8 panels scaled to the lobe's width around
    its peak (t* = the mean of wi's and wo's projected angles, or the nearest lit
    point when the peak is shadowed) and clipped to the lobe's support.

    Departures from the paper, for the standard of this library: the per-point
    specular term is the reciprocal, normalised modified Phong lobe (with its
    (n.wi) factor), so the model is **reciprocal** and **conserves energy**
    (directional albedo <= rho_d + rho_s: the lit projected width of a period is
    exactly P cos_i, and masking only removes light); only single scattering; the
    subtracted cylinders (grooves) and h > 1 (undercut cylinders) are not modelled.
    Limits: spacing -> infinity or height -> 0 give the flat modified Phong
    (isotropic). Symmetric under phi -> phi + pi. The paper's text was not at hand when this was
    written: the equations here are derived from its geometry, not copied, and
    its equation numbers could not be checked, so none are cited.

    Parameters: ``rho_d``, ``rho_s`` (albedos, [0, 1]), ``exponent`` (Phong
    exponent > 0), ``spacing`` (d, in cylinder radii, >= 0), ``height`` (h, in
    cylinder radii, clamped to [H_MIN, 1]).
    """

    rho_d: Float[Array, "*batch C"]
    rho_s: Float[Array, "*batch C"]
    exponent: Float[Array, "*batch C"]
    spacing: Float[Array, "*batch C"]
    height: Float[Array, "*batch C"]

    def __init__(self, rho_d: ArrayLike, rho_s: ArrayLike, exponent: ArrayLike, spacing: ArrayLike = 0.0,
                 height: ArrayLike = 1.0):
        self.rho_d = as_param("PoulinFournier", "rho_d", rho_d, lower=0.0)
        self.rho_s = as_param("PoulinFournier", "rho_s", rho_s, lower=0.0)
        self.exponent = as_param("PoulinFournier", "exponent", exponent, lower=0.0)
        self.spacing = as_param("PoulinFournier", "spacing", spacing, lower=0.0)
        self.height = as_param("PoulinFournier", "height", height, lower=0.0, upper=1.0, lower_open=True)

    def __call__(self, wi: Float[Array, "*batch 3"], wo: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """f_r in 1/sr; 0 below the horizon."""
        wi, wo = check_directions("PoulinFournier", wi, wo)
        check_module_rank(self, wi.ndim)
        ci, co = cos_theta(wi), cos_theta(wo)
        active = (ci > 0) & (co > 0)
        # the cosines raised to the grazing floor (brdf._safe.GRAZING_ULPS) bound the
        # 1/(cos_i cos_o) of the cap integral, and keep every quantity below finite in
        # the masked lanes too, with its gradient; the lobe's cosines are clipped to 1
        # (brdf.clamp_cos: for vectors that are not unit length r.wo can exceed 1, and
        # r.wo^exponent overflows)
        wi, wo = lift_grazing(wi), lift_grazing(wo)
        ci_s, co_s = cos_theta(wi), cos_theta(wo)
        wx, wy = wi[..., 0:1], wi[..., 1:2]
        vx, vy = wo[..., 0:1], wo[..., 1:2]

        h = jnp.clip(self.height, H_MIN, 1.0)
        d = self.spacing
        n = self.exponent
        t_max = 2.0 * jnp.arcsin(jnp.sqrt(0.5 * h))  # acos(1 - h), accurate for small h
        w = jnp.sin(t_max)
        c = h - 1.0
        period = 2.0 * w + d

        a_i, lo_i, hi_i, base_i, pos_i = _lit_interval(wy, ci_s, t_max, c, w, d, period)
        a_o, lo_o, hi_o, base_o, pos_o = _lit_interval(vy, co_s, t_max, c, w, d, period)
        lo = jnp.maximum(lo_i, lo_o)
        hi = jnp.maximum(jnp.minimum(hi_i, hi_o), lo)
        length = hi - lo

        # diffuse: integral of (n.wi)(n.wo) over [lo, hi], n.w = w_y sin t + w_z cos t
        s = lo + hi
        sin_len = jnp.sin(length)
        cap_cos = 0.5 * (
            (wy * vy + ci_s * co_s) * length
            + (ci_s * co_s - wy * vy) * jnp.cos(s) * sin_len
            + (wy * co_s + ci_s * vy) * jnp.sin(s) * sin_len
        )

        # specular: r.wo = A cos(2t - a_i - a_o) - wx vx, A = |p_i| |p_o| (p: projection on y-z)
        big_a = jnp.sqrt((wy * wy + ci_s * ci_s) * (vy * vy + co_s * co_s))
        cx = wx * vx
        t_peak = 0.5 * (a_i + a_o)
        half_support = 0.5 * _acos_edges(cx / big_a)
        lo_s = jnp.clip(t_peak - half_support, lo, hi)
        hi_s = jnp.clip(t_peak + half_support, lo_s, hi)
        # Panels around the point of [lo_s, hi_s] nearest the peak, t_c, scaled by the
        # lobe's local decay length there: its Gaussian width sigma at the peak, or
        # sigma^2 / delta on a tail at a distance delta from a peak that is shadowed.
        sigma = 0.5 * safe_sqrt(safe_div(big_a - cx, n * big_a))  # Gaussian width of the lobe in t
        t_c = jnp.clip(t_peak, lo_s, hi_s)
        scale = safe_div(sigma * sigma, jnp.abs(t_peak - t_c) + sigma)
        edges = [lo_s]
        for m in _PANEL_EDGES:
            edges.append(jnp.clip(t_c + m * scale, edges[-1], hi_s))
        edges.append(hi_s)
        spec = _specular_panels(edges, wy, ci_s, vy, co_s, dot(wi, wo), n, N_NODES)

        cap = (self.rho_d / jnp.pi * cap_cos + self.rho_s * (n + 2.0) / (2.0 * jnp.pi) * spec) / (ci_s * co_s)

        # the flat base between caps: lit and visible length, then the flat micro-BRDF
        same_side = pos_i == pos_o
        base = jnp.where(same_side, jnp.minimum(base_i, base_o), jnp.maximum(base_i + base_o - d, 0.0))
        mirror_dot = ci_s * co_s - wx * vx - wy * vy  # reflect(wi, z).wo
        flat = self.rho_d / jnp.pi + self.rho_s * (n + 2.0) / (2.0 * jnp.pi) * safe_pow(clamp_cos(mirror_dot), n)

        f = (cap + flat * base) / period
        return jnp.where(active, jnp.maximum(f, 0.0), 0.0)

    def fittable(self) -> dict[str, ParamSpec]:
        """``rho_d``, ``rho_s`` in (0, 1) (sigmoid); ``exponent`` > 0 (exp);
        ``spacing`` > 0 (softplus); ``height`` in (H_MIN, 1) (sigmoid)."""
        return {"rho_d": _RHO, "rho_s": _RHO, "exponent": _EXPONENT, "spacing": _SPACING, "height": _HEIGHT}


def _specular_panels(edges, wy, wz, vy, vz, wi_dot_wo, n, n_nodes):
    """sum over the panels [edges[j], edges[j+1]] of the Gauss-Legendre estimate of
    integral (n.wi)(n.wo) max(0, r.wo)^n dt, r.wo = 2 (n.wi)(n.wo) - wi.wo."""
    x, wgt = np.polynomial.legendre.leggauss(n_nodes)
    nd = edges[0].ndim
    shape = (1,) * nd + (n_nodes,)
    x = jnp.asarray(x.reshape(shape), edges[0].dtype)
    wgt = jnp.asarray(wgt.reshape(shape), edges[0].dtype)

    def ex(v):  # 0-d parameters stay 0-d
        return jnp.expand_dims(v, -1) if v.ndim == nd else v

    wy, wz, vy, vz, wi_dot_wo, n = map(ex, (wy, wz, vy, vz, wi_dot_wo, n))
    total = 0.0
    for p0, p1 in zip(edges[:-1], edges[1:], strict=True):
        half = ex(0.5 * (p1 - p0))
        t = ex(0.5 * (p0 + p1)) + half * x
        st, ct = jnp.sin(t), jnp.cos(t)
        ni = jnp.maximum(wy * st + wz * ct, 0.0)
        no = jnp.maximum(vy * st + vz * ct, 0.0)
        lobe = safe_pow(clamp_cos(2.0 * ni * no - wi_dot_wo), n)
        total = total + jnp.sum(wgt * half * ni * no * lobe, axis=-1)
    return total

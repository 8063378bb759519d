"""Classical dipole of Jensen, Marschner, Levoy & Hanrahan 2001, "A Practical
Model for Subsurface Light Transport" (SIGGRAPH 2001), section 4."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from brdf import safe_sqrt

from ._common import (
    ETA_MAX,
    ETA_MIN,
    AbstractProfile,
    align,
    as_float,
    channels,
    check,
    fresnel_diffuse_reflectance,
    radius_arg,
)


def check_coefficients(owner: str, sigma_a, sigma_s_prime, eta) -> None:
    """Concrete-value checks shared by the dipole family."""
    check(owner, "sigma_a (1/mm)", sigma_a, lo=0.0)
    check(owner, "sigma_s_prime (1/mm)", sigma_s_prime, lo=0.0)
    check(owner, "eta (relative index of refraction)", eta, lo=ETA_MIN, hi=ETA_MAX)
    check(owner, "sigma_a + sigma_s_prime (1/mm)", as_float(sigma_a) + as_float(sigma_s_prime), lo=0.0, lo_open=True)


def dipole_term(r: Array, z: Array, sigma_tr: Array) -> Array:
    """One real or virtual source of the dipole: z (1 + sigma_tr d) exp(-sigma_tr d) / d^3
    with d = sqrt(r^2 + z^2) (Jensen et al. 2001, eq. 4, without alpha'/4pi).
    Finite with a zero r-gradient at r = 0 because |z| > 0."""
    d = jnp.sqrt(r * r + z * z)
    return z * (1 + sigma_tr * d) * jnp.exp(-sigma_tr * d) / d**3


def dipole_term_cumulative(r: Array, z: Array, sigma_tr: Array) -> Array:
    """Closed-form integral of 2 pi s dipole_term(s) over s in [0, r]:
    2 pi z (exp(-sigma_tr |z|)/|z| - exp(-sigma_tr d)/d), d = sqrt(r^2 + z^2)
    (d/dd [-exp(-sigma d)/d] = (1 + sigma d) exp(-sigma d)/d^2 and s ds = d dd)."""
    d = jnp.sqrt(r * r + z * z)
    az = jnp.abs(z)
    return 2 * jnp.pi * z * (jnp.exp(-sigma_tr * az) / az - jnp.exp(-sigma_tr * d) / d)


class Dipole(AbstractProfile):
    """Classical dipole diffusion profile (Jensen et al. 2001, eqs. 4-5).

    Per colour channel: ``sigma_a`` absorption and ``sigma_s_prime`` reduced
    scattering coefficients in 1/mm (>= 0, sum > 0), ``eta`` the relative index
    of refraction of the medium (1 <= eta <= 3). Fields broadcast to ``[..., C]``
    (scalars give C = 1). A(eta) = (1 + F_dr)/(1 - F_dr) with the paper's
    polynomial F_dr. ``g`` (mean cosine of the phase function, |g| < 1) is used
    only by the single-scattering term.
    """

    sigma_a: Float[Array, "*pbatch channel"]
    sigma_s_prime: Float[Array, "*pbatch channel"]
    eta: Float[Array, "*pbatch channel"]
    g: Float[Array, "*pbatch channel"]

    def __init__(self, sigma_a: ArrayLike, sigma_s_prime: ArrayLike, eta: ArrayLike = 1.3, g: ArrayLike = 0.0):
        check_coefficients("Dipole", sigma_a, sigma_s_prime, eta)
        check("Dipole", "g (phase-function mean cosine)", g, lo=-1.0, hi=1.0, lo_open=True, hi_open=True)
        self.sigma_a, self.sigma_s_prime, self.eta, self.g = channels(sigma_a, sigma_s_prime, eta, g)

    @property
    def batch_shape(self) -> tuple[int, ...]:
        """Parameter batch shape (the axes before the channel axis)."""
        return self.sigma_a.shape[:-1]

    # --- derived quantities (Jensen et al. 2001, section 4) -----------------
    @property
    def sigma_t_prime(self) -> Array:
        """Reduced extinction sigma_t' = sigma_a + sigma_s' (1/mm)."""
        return self.sigma_a + self.sigma_s_prime

    @property
    def alpha_prime(self) -> Array:
        """Reduced albedo alpha' = sigma_s' / sigma_t'."""
        return self.sigma_s_prime / self.sigma_t_prime

    @property
    def sigma_tr(self) -> Array:
        """Effective transport coefficient sqrt(3 sigma_a sigma_t') (1/mm)."""
        # safe_sqrt: finite (zero) gradient at sigma_a = 0 (albedo 1).
        return safe_sqrt(3 * self.sigma_a * self.sigma_t_prime)

    @property
    def A(self) -> Array:
        """Boundary mismatch A = (1 + F_dr)/(1 - F_dr)."""
        fdr = fresnel_diffuse_reflectance(self.eta)
        return (1 + fdr) / (1 - fdr)

    @property
    def z_r(self) -> Array:
        """Depth of the real source, 1/sigma_t' (mm)."""
        return 1 / self.sigma_t_prime

    @property
    def z_v(self) -> Array:
        """Height of the virtual source above the surface, z_r (1 + 4A/3) (mm)."""
        return self.z_r * (1 + 4 * self.A / 3)

    # --- profile --------------------------------------------------------------
    def radial(self, r: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch channel"]:
        """R_d(r) = alpha'/(4 pi) [z_r (1 + sigma_tr d_r) e^{-sigma_tr d_r}/d_r^3
        + z_v (1 + sigma_tr d_v) e^{-sigma_tr d_v}/d_v^3] in 1/mm^2
        (Jensen et al. 2001, eq. 4); r in mm, shape [...] -> [..., C]."""
        r = radius_arg("Dipole.radial", r, self.sigma_a.dtype)
        return _radial(r, self.sigma_a, self.sigma_s_prime, self.eta)

    def total(self) -> Float[Array, "*pbatch channel"]:
        """Total diffuse reflectance (Jensen et al. 2001, eq. 5):
        R_d = (alpha'/2) (1 + e^{-(4/3) A sqrt(3(1 - alpha'))}) e^{-sqrt(3(1 - alpha'))}."""
        return _total(self.sigma_a, self.sigma_s_prime, self.eta)

    def cumulative(self, r: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch channel"]:
        """Energy within radius r (mm), closed form of eq. 4 integrated over the disc."""
        r = radius_arg("Dipole.cumulative", r, self.sigma_a.dtype)
        return _cumulative(r, self.sigma_a, self.sigma_s_prime, self.eta)

    def single_scattering(
        self, wi: Float[ArrayLike, "*batch 3"], wo: Float[ArrayLike, "*batch 3"]
    ) -> Float[Array, "*batch channel"]:
        """Single-scattering term as a BRDF f_r(wi, wo) in 1/sr, the optional first-order
        term of Jensen et al. 2001 (section 3.2; for a flat semi-infinite medium it is
        Hanrahan & Krueger 1993's eq. 21):
        f = alpha T(wi) T(wo) p(t_i . t_o) / (eta^2 (cos t_i + cos t_o)),
        alpha = sigma_s/sigma_t with sigma_s = sigma_s'/(1 - g), T = 1 - Fresnel, p the
        Henyey-Greenstein phase function of the refracted directions t_i, t_o, and
        1/eta^2 the radiance change on leaving the medium. Directions in the local
        frame (z = normal), pointing away from the surface; 0 below the horizon.
        No cosine factor (multiply by cos theta_i to integrate against radiance)."""
        return _single_scattering(jnp.asarray(wi), jnp.asarray(wo), self.sigma_a, self.sigma_s_prime, self.eta, self.g)


def _fresnel_external(cos_i, eta):
    """Unpolarised Fresnel reflectance from outside (index 1) into the medium (eta >= 1)."""
    cos_t = jnp.sqrt(jnp.clip(1 - (1 - cos_i * cos_i) / (eta * eta), 0.0, 1.0))
    rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return 0.5 * (rs * rs + rp * rp), cos_t


@jax.jit
def _single_scattering(wi, wo, sigma_a, sigma_s_prime, eta, g):
    ci, co = wi[..., 2:3], wo[..., 2:3]
    up = (ci > 0) & (co > 0)
    # double where: below-horizon lanes evaluate at a harmless cosine (gradient 0, not NaN)
    ci_s, co_s = jnp.where(up, ci, 1.0), jnp.where(up, co, 1.0)
    ci, co, sa, ss, eta, g = align(ci_s, co_s, sigma_a, sigma_s_prime, eta, g)
    wi_xy, wo_xy = align(wi[..., :2], wo[..., :2], ci)[:2]
    Fi, cti = _fresnel_external(ci, eta)
    Fo, cto = _fresnel_external(co, eta)
    sigma_s = ss / (1 - g)
    albedo = sigma_s / (sigma_s + sa)
    # propagation directions inside: t_i = (-wi_xy/eta, -cos t_i), t_o = (wo_xy/eta, cos t_o)
    cos_phase = -jnp.sum(wi_xy * wo_xy, axis=-1, keepdims=True) / (eta * eta) - cti * cto
    hg = (1 - g * g) / (4 * jnp.pi * (1 + g * g - 2 * g * cos_phase) ** 1.5)
    f = albedo * (1 - Fi) * (1 - Fo) * hg / (eta * eta * (cti + cto))
    f, upa = align(f, up)
    return jnp.where(upa, f, 0.0)


def _geometry(sigma_a, sigma_s_prime, eta):
    """alpha', sigma_tr, z_r, z_v of the classical dipole (Jensen et al. 2001, section 4)."""
    st = sigma_a + sigma_s_prime
    fdr = fresnel_diffuse_reflectance(eta)
    A = (1 + fdr) / (1 - fdr)
    zr = 1 / st
    # safe_sqrt: finite (zero) gradient at sigma_a = 0 (albedo 1).
    return sigma_s_prime / st, safe_sqrt(3 * sigma_a * st), zr, zr * (1 + 4 * A / 3), A


# The kernels are jitted pure functions: one compiled call per shape instead of
# a few dozen eager primitive dispatches (and they nest under outer jit/grad/vmap).
@jax.jit
def _radial(r, sigma_a, sigma_s_prime, eta):
    a, st, zr, zv, _ = _geometry(sigma_a, sigma_s_prime, eta)
    r, a, zr, zv, st = align(r, a, zr, zv, st)
    return a / (4 * jnp.pi) * (dipole_term(r, zr, st) + dipole_term(r, zv, st))


@jax.jit
def _cumulative(r, sigma_a, sigma_s_prime, eta):
    a, st, zr, zv, _ = _geometry(sigma_a, sigma_s_prime, eta)
    r, a, zr, zv, st = align(r, a, zr, zv, st)
    return a / (4 * jnp.pi) * (dipole_term_cumulative(r, zr, st) + dipole_term_cumulative(r, zv, st))


@jax.jit
def _total(sigma_a, sigma_s_prime, eta):
    a, _, _, _, A = _geometry(sigma_a, sigma_s_prime, eta)
    u = safe_sqrt(3 * (1 - a))
    return 0.5 * a * (1 + jnp.exp(-4 / 3 * A * u)) * jnp.exp(-u)

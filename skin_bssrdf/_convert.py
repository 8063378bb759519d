"""Conversions between the physical coefficients (sigma_a, sigma_s', eta) and
what artists and fitters use: the total diffuse reflectance ("albedo") and a
mean free path, per channel (Jensen & Buhler 2002, "A Rapid Hierarchical
Rendering Technique for Translucent Materials", section 4; Hery 2012 for the
better dipole).

The total diffuse reflectance of the dipole family depends only on the reduced
albedo alpha' = sigma_s'/sigma_t' and eta, and is increasing in alpha'. It is
inverted in the variable u = sqrt(1 - alpha') in [0, 1], in which it is smooth
at both ends (in alpha' its slope is infinite at alpha' = 1), by bisection (a
fixed number of steps, so it is jit/vmap safe) followed by one Newton step
whose derivative is held constant: the value is the bisection's, and the
gradient is the implicit-function gradient du/dRd = 1/Rd'(u) (plus the eta
dependence), finite everywhere including albedo 0 and 1.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from brdf import safe_div, safe_sqrt

from ._better_dipole import _total as _better_total
from ._common import (
    ETA_MAX,
    ETA_MIN,
    as_float,
    channels,
    check,
    fresnel_diffuse_reflectance,
    fresnel_moments,
    one_minus_exp_over,
)
from ._dipole import _total as _dipole_total

MODELS = ("dipole", "better_dipole")
MFP_KINDS = ("diffuse", "transport")

# Bisection steps: 60 halvings of [0, 1] reach float64 rounding (2^-60 ~ 1e-18).
_STEPS = 60

# Named floor: with the diffuse mean free path 1/sigma_tr, albedo 1 (alpha' = 1)
# means sigma_a = 0 and an infinite diffuse mean free path, so u = sqrt(1 - alpha')
# is kept >= 1e-6 (alpha' <= 1 - 1e-12). Rd(u) ~ 1 - c u near u = 0 (c ~ 5), so
# the albedo this can represent tops out ~5e-6 below 1: far below what a sensor
# records, while sigma_t' = 1/(mfp sqrt(3) u) stays finite in float32.
_U_MIN_DIFFUSE = 1e-6


def total_from_reduced_albedo(alpha_prime: ArrayLike, eta: ArrayLike = 1.3, model: str = "dipole") -> Array:
    """Total diffuse reflectance Rd(alpha', eta) of a semi-infinite medium.

    Args:
        alpha_prime: reduced scattering albedo alpha' = sigma_s' / sigma_t', in [0, 1].
        eta: relative refractive index of the medium (>= 1).
        model: ``"dipole"`` (Jensen et al. 2001) or ``"better_dipole"`` (d'Eon 2012).

    Returns:
        Rd in [0, 1], the broadcast shape.

    References:
        Jensen et al. 2001, "A practical model for subsurface light transport", eq. 5 (``"dipole"``);
        Hery 2012 / d'Eon 2012, "A better dipole" (``"better_dipole"``).
    """
    _check_model("total_from_reduced_albedo", model)
    check("total_from_reduced_albedo", "alpha_prime", alpha_prime, lo=0.0, hi=1.0)
    check("total_from_reduced_albedo", "eta", eta, lo=ETA_MIN, hi=ETA_MAX)
    a, eta = channels(alpha_prime, eta)
    return _rd_jit(a, eta, model=model)


def _rd(a, eta, model):
    u = safe_sqrt(1 - a)
    return _rd_u(u, _constants(eta, model), model)


_rd_jit = jax.jit(lambda a, eta, *, model: _rd(a, eta, model), static_argnames="model")


def _constants(eta, model):
    """The eta-only constants of Rd, computed once outside the bisection loop."""
    if model == "dipole":
        fdr = fresnel_diffuse_reflectance(eta)
        return ((1 + fdr) / (1 - fdr),)
    c1, c2 = fresnel_moments(eta)
    return (1 + 3 * c2) / (1 - 2 * c1), (1 - 2 * c1) / 4, (1 - 3 * c2) / 2


def _rd_u(u, consts, model):
    """Rd as a function of u = sqrt(1 - alpha'), smooth on [0, 1].

    Classical (Jensen et al. 2001 eq. 5): alpha'/2 (1 + e^{-(4/3) A sqrt(3) u}) e^{-sqrt(3) u}.
    Better dipole (Hery 2012): alpha'^2/2 e^{-y} [C_E (1 + e^{-x}) + 4 A C_phi (1 - e^{-x})/x],
    y = sigma_tr z_r = sqrt(3) u / sqrt(1 + u^2), x = 4 A D sigma_tr = 4 A u sqrt(1 + u^2) / sqrt(3).
    """
    a = 1 - u * u
    if model == "dipole":
        (A,) = consts
        v = jnp.sqrt(3.0) * u
        return 0.5 * a * (1 + jnp.exp(-4 / 3 * A * v)) * jnp.exp(-v)
    A, cphi, ce = consts
    w = jnp.sqrt(1 + u * u)
    y = jnp.sqrt(3.0) * u / w
    x = 4 * A * u * w / jnp.sqrt(3.0)
    return 0.5 * a * a * jnp.exp(-y) * (ce * (1 + jnp.exp(-x)) + 4 * A * cphi * one_minus_exp_over(x))


def reduced_albedo_from_total(albedo: ArrayLike, eta: ArrayLike = 1.3, model: str = "dipole") -> Array:
    """The reduced albedo alpha' whose total diffuse reflectance Rd(alpha', eta) is ``albedo``.

    The inverse of ``total_from_reduced_albedo``, stable and differentiable (see the module docstring).

    Args:
        albedo: total diffuse reflectance, in [0, 1].
        eta: relative refractive index of the medium (>= 1).
        model: ``"dipole"`` (Jensen et al. 2001) or ``"better_dipole"`` (d'Eon 2012).

    Returns:
        alpha' in [0, 1], the broadcast shape.

    References:
        Jensen & Buhler 2002, "A rapid hierarchical rendering technique for translucent materials", sec. 4.
    """
    _check_model("reduced_albedo_from_total", model)
    check("reduced_albedo_from_total", "albedo", albedo, lo=0.0, hi=1.0)
    check("reduced_albedo_from_total", "eta", eta, lo=ETA_MIN, hi=ETA_MAX)
    rd, eta = channels(albedo, eta)
    return _alpha_jit(rd, eta, model=model)


def _alpha_impl(rd, eta, *, model):
    u = _invert_u_impl(rd, eta, model=model)
    return 1 - u * u


_alpha_jit = jax.jit(_alpha_impl, static_argnames="model")


def _invert_u_impl(rd, eta, *, model):
    rd = jnp.clip(rd, 0.0, 1.0)
    consts = _constants(eta, model)
    # the search itself is not differentiated: it runs on constants
    rd0 = jax.lax.stop_gradient(rd)
    c0 = jax.lax.stop_gradient(consts)

    def body(_, bounds):
        lo, hi = bounds
        mid = 0.5 * (lo + hi)
        too_bright = _rd_u(mid, c0, model) > rd0  # Rd falls with u
        return jnp.where(too_bright, mid, lo), jnp.where(too_bright, hi, mid)

    lo, hi = jax.lax.fori_loop(0, _STEPS, body, (jnp.zeros_like(rd0), jnp.ones_like(rd0)))
    u0 = 0.5 * (lo + hi)
    # implicit-function gradient: u = u0 - (Rd(u0) - rd) / Rd'(u0) with Rd' held constant.
    # The value is u0 (the correction is zero in value); d u/d rd = 1/Rd'(u0) and
    # d u/d eta = -(dRd/deta)/Rd'(u0). Rd'(u) < 0 on (0, 1] for both models.
    slope = jax.grad(lambda x: jnp.sum(_rd_u(x, c0, model)))(u0)
    resid = _rd_u(u0, consts, model) - rd
    # safe_div: the better dipole's Rd ~ alpha'^2 has zero slope at albedo 0, where
    # the true du/dRd is infinite; the gradient is 0 there instead of NaN.
    return u0 - safe_div(resid - jax.lax.stop_gradient(resid), slope)



def coefficients_from_albedo(
    albedo: ArrayLike,
    mfp: ArrayLike,
    eta: ArrayLike = 1.3,
    model: str = "dipole",
    mfp_kind: str = "diffuse",
) -> tuple[Float[Array, "*batch channel"], Float[Array, "*batch channel"]]:
    """Scattering coefficients (sigma_a, sigma_s') from a total diffuse reflectance and a mean free path.

    Args:
        albedo: total diffuse reflectance, in [0, 1]; albedo 1 is held at the named floor alpha' <= 1 - 1e-12
            (an albedo ~5e-6 below 1).
        mfp: mean free path (mm, > 0).
        eta: relative refractive index of the medium (>= 1).
        model: ``"dipole"`` (Jensen et al. 2001) or ``"better_dipole"`` (d'Eon 2012).
        mfp_kind: ``"diffuse"``: mfp = 1 / sigma_tr, the diffuse mean free path that sets the profile's width
            (sigma_tr of the chosen model); ``"transport"``: mfp = 1 / sigma_t'.

    Returns:
        (sigma_a, sigma_s') in 1/mm, the broadcast shape.

    References:
        Jensen & Buhler 2002, "A rapid hierarchical rendering technique for translucent materials", sec. 4.
    """
    owner = "coefficients_from_albedo"
    _check_model(owner, model)
    if mfp_kind not in MFP_KINDS:
        raise ValueError(f"{owner}: mfp_kind must be one of {MFP_KINDS}, got {mfp_kind!r}")
    check(owner, "albedo", albedo, lo=0.0, hi=1.0)
    check(owner, "mfp (mm)", mfp, lo=0.0, lo_open=True)
    check(owner, "eta", eta, lo=ETA_MIN, hi=ETA_MAX)
    rd, mfp, eta = channels(albedo, mfp, eta)
    return _coefficients(rd, mfp, eta, model, mfp_kind)


def _coefficients(rd, mfp, eta, model, mfp_kind):
    return _coefficients_jit(rd, mfp, eta, model=model, mfp_kind=mfp_kind)


def _coefficients_impl(rd, mfp, eta, *, model, mfp_kind):
    u = _invert_u_impl(rd, eta, model=model)
    if mfp_kind == "transport":
        st = 1 / mfp
    else:
        u = jnp.maximum(u, _U_MIN_DIFFUSE)
        st = 1 / (mfp * _tr_over_t(u, model))
    # sigma_a from u^2 directly: 1 - alpha' would cancel catastrophically near albedo 1
    return u * u * st, (1 - u * u) * st


_coefficients_jit = jax.jit(_coefficients_impl, static_argnames=("model", "mfp_kind"))


def _tr_over_t(u, model):
    """sigma_tr / sigma_t' as a function of u = sqrt(1 - alpha'):
    sqrt(3) u (classical) or sqrt(3 / (1 + u^2)) u (better dipole, D = (1 + (1 - alpha'))/(3 sigma_t'))."""
    if model == "dipole":
        return jnp.sqrt(3.0) * u
    return jnp.sqrt(3 / (1 + u * u)) * u


def albedo_from_coefficients(
    sigma_a: ArrayLike,
    sigma_s_prime: ArrayLike,
    eta: ArrayLike = 1.3,
    model: str = "dipole",
    mfp_kind: str = "diffuse",
) -> tuple[Float[Array, "*batch channel"], Float[Array, "*batch channel"]]:
    """Total diffuse reflectance and mean free path from scattering coefficients (sigma_a, sigma_s').

    The inverse of ``coefficients_from_albedo``.

    Args:
        sigma_a: absorption coefficient (1/mm, >= 0).
        sigma_s_prime: reduced scattering coefficient (1/mm, > 0).
        eta: relative refractive index of the medium (>= 1).
        model: ``"dipole"`` (Jensen et al. 2001) or ``"better_dipole"`` (d'Eon 2012).
        mfp_kind: ``"diffuse"`` (1 / sigma_tr) or ``"transport"`` (1 / sigma_t'), as in
            ``coefficients_from_albedo``.

    Returns:
        (albedo in [0, 1], mean free path in mm); the diffuse mean free path is Inf where sigma_a = 0 (nothing is
        absorbed, light spreads without bound).

    References:
        Jensen & Buhler 2002, "A rapid hierarchical rendering technique for translucent materials", sec. 4.
    """
    owner = "albedo_from_coefficients"
    _check_model(owner, model)
    if mfp_kind not in MFP_KINDS:
        raise ValueError(f"{owner}: mfp_kind must be one of {MFP_KINDS}, got {mfp_kind!r}")
    check(owner, "sigma_a (1/mm)", sigma_a, lo=0.0)
    check(owner, "sigma_s_prime (1/mm)", sigma_s_prime, lo=0.0)
    check(owner, "sigma_a + sigma_s_prime (1/mm)", as_float(sigma_a) + as_float(sigma_s_prime), lo=0.0, lo_open=True)
    check(owner, "eta", eta, lo=ETA_MIN, hi=ETA_MAX)
    sa, ss, eta = channels(sigma_a, sigma_s_prime, eta)
    return _albedo_jit(sa, ss, eta, model=model, mfp_kind=mfp_kind)


def _albedo_impl(sa, ss, eta, *, model, mfp_kind):
    st = sa + ss
    rd = (_dipole_total if model == "dipole" else _better_total)(sa, ss, eta)
    if mfp_kind == "transport":
        return rd, 1 / st
    u = safe_sqrt(sa / st)
    return rd, 1 / (st * _tr_over_t(u, model))


_albedo_jit = jax.jit(_albedo_impl, static_argnames=("model", "mfp_kind"))


def _check_model(owner, model):
    if model not in MODELS:
        raise ValueError(f"{owner}: model must be one of {MODELS}, got {model!r}")


__all__ = [
    "albedo_from_coefficients",
    "coefficients_from_albedo",
    "reduced_albedo_from_total",
    "total_from_reduced_albedo",
    "fresnel_diffuse_reflectance",
]

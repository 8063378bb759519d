"""Fresnel reflectance: free functions of cos(theta_d) = dot(wi, wm), and the
Modules that hold their parameters for ``Microfacet``. The free functions are
elementwise, so they serve the Modules' [*batch, 1] cosines and the fitter's
component-major [N] rows alike."""

from __future__ import annotations

import abc

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._base import ParamSpec, as_param
from ._safe import safe_div, safe_hypot, safe_sqrt


def schlick(cos_theta: Float[ArrayLike, "*#shape"], f0: Float[ArrayLike, "*#shape"]) -> Float[Array, "*shape"]:
    """Schlick's approximation F = f0 + (1 - f0) (1 - cos)^5 (Schlick 1994,
    "An inexpensive BRDF model for physically-based rendering", eq. 15).

    ``cos_theta`` = dot(wi, wm), clamped to [0, 1]; ``f0`` is the reflectance at
    normal incidence (dimensionless, in [0, 1]). Elementwise, so it serves both
    layouts: [*batch, 1] with f0 [*batch, C] gives [*batch, C]; component-major
    [N] rows give [N]. Dimensionless; f0 at cos = 1, 1 at cos = 0.
    """
    c = jnp.clip(cos_theta, 0.0, 1.0)
    m = 1.0 - c
    m2 = m * m
    return f0 + (1.0 - f0) * (m2 * m2 * m)



def fresnel_dielectric(
    cos_theta: Float[ArrayLike, "*#shape"], eta: Float[ArrayLike, "*#shape"]
) -> Float[Array, "*shape"]:
    """Exact unpolarised Fresnel reflectance of a smooth dielectric interface
    (Born & Wolf §1.5.2; pbrt-v4 §9.3, FrDielectric).

    ``eta`` = eta_t / eta_i (> 0), ``cos_theta`` >= 0 on the incident side
    (clamped to [0, 1]). Returns 1 under total internal reflection.
    Elementwise: [*batch, 1] cosines with [*batch, C] indices give [*batch, C].
    """
    c = jnp.clip(cos_theta, 0.0, 1.0)
    eta = jnp.asarray(eta)
    sin2_t = safe_div(1.0 - c * c, eta * eta, fallback=2.0)
    tir = sin2_t >= 1.0
    cos_t = safe_sqrt(1.0 - sin2_t)
    r_parl = safe_div(eta * c - cos_t, eta * c + cos_t, fallback=1.0)
    r_perp = safe_div(c - eta * cos_t, c + eta * cos_t, fallback=1.0)
    return jnp.where(tir, 1.0, 0.5 * (r_parl * r_parl + r_perp * r_perp))


def fresnel_transmittance(
    cos_theta: Float[ArrayLike, "*#shape"], eta: Float[ArrayLike, "*#shape"]
) -> Float[Array, "*shape"]:
    """Fraction of light transmitted through a smooth dielectric interface,
    1 - F_dielectric(clip(cos_theta, 0, 1), eta) (energy conservation at the
    interface; pbrt-v4 §9.3, FrDielectric). Dimensionless, in [0, 1]:
    1 - ((eta - 1) / (eta + 1))^2 at normal incidence, 0 at grazing and under
    total internal reflection. ``eta`` = eta_t / eta_i > 0 (skin seen from air:
    1.4); ``cos_theta`` is the cosine on the incident side. The F_t factors in
    and out of a diffusion BSSRDF (Jensen et al. 2001, "A practical model for
    subsurface light transport", S_d). Elementwise (any layout).
    """
    return 1.0 - fresnel_dielectric(cos_theta, eta)  # fresnel_dielectric clamps cos_theta


def fresnel_complex(
    cos_theta: Float[Array, "*batch 1"],
    eta_m: ArrayLike,
    kappa_m: ArrayLike,
    eta_a: ArrayLike = 1.0,
    kappa_a: ArrayLike = 0.0,
) -> Float[Array, "*batch C"]:
    """Exact unpolarised Fresnel reflectance for a complex index of refraction
    between two media, in the F_s, F_p, a, b form used by Cook & Torrance 1982
    (ACM TOG 1(1), after Sparrow & Cess; also Born & Wolf §13.2):

        a^2, b^2 = (sqrt((n^2 - k^2 - sin^2)^2 + 4 n^2 k^2) +- (n^2 - k^2 - sin^2)) / 2
        F_s = ((a - cos)^2 + b^2) / ((a + cos)^2 + b^2)
        F_p = F_s ((a - sin tan)^2 + b^2) / ((a + sin tan)^2 + b^2)
        F   = (F_s + F_p) / 2

    with n + i k the relative index (eta_m + i kappa_m) / (eta_a + i kappa_a) of the
    material m seen from the ambient medium a. The F_p line is evaluated
    multiplied through by cos^2, so it is finite at normal and grazing incidence,
    and both lines' numerators are written as sums of squares, so F >= 0 after rounding.
    For an absorbing ambient medium (kappa_a > 0) this is the usual relative-index
    approximation. Dimensionless, in [0, 1]; at normal incidence in vacuum it
    equals ((n - 1)^2 + k^2) / ((n + 1)^2 + k^2).
    """
    c = jnp.clip(cos_theta, 0.0, 1.0)
    eta_m, kappa_m, eta_a, kappa_a = (jnp.asarray(v) for v in (eta_m, kappa_m, eta_a, kappa_a))
    den = eta_a * eta_a + kappa_a * kappa_a
    n = (eta_m * eta_a + kappa_m * kappa_a) / den
    k = (kappa_m * eta_a - eta_m * kappa_a) / den
    c2 = c * c
    s2 = 1.0 - c2
    t1 = n * n - k * k - s2
    a2pb2 = safe_hypot(t1, 2.0 * n * k)  # a^2 + b^2
    a = safe_sqrt(0.5 * (a2pb2 + t1))
    b2 = jnp.maximum(0.5 * (a2pb2 - t1), 0.0)
    # numerators as sums of squares, ((a - cos)^2 + b^2 and (a cos - sin^2)^2 + b^2 cos^2):
    # >= 0 after rounding, where term1 - term2 would cancel to -1e-8 (index matched, n = 1, k = 0)
    r_s = safe_div((a - c) ** 2 + b2, (a + c) ** 2 + b2, fallback=1.0)
    ac = a * c
    b2c2 = b2 * c2
    r_p = r_s * safe_div((ac - s2) ** 2 + b2c2, (ac + s2) ** 2 + b2c2, fallback=1.0)
    return 0.5 * (r_s + r_p)


def fresnel_conductor(
    cos_theta: Float[Array, "*batch 1"], eta: ArrayLike, k: ArrayLike
) -> Float[Array, "*batch C"]:
    """Exact unpolarised Fresnel reflectance of a conductor with complex index
    eta + i k seen from vacuum (pbrt-v4 §9.3, FrComplex; Mitsuba 3's
    ``fresnel_conductor``): :func:`fresnel_complex` with eta_a = 1, kappa_a = 0."""
    return fresnel_complex(cos_theta, eta, k, 1.0, 0.0)


class AbstractFresnel(eqx.Module):
    """Fresnel reflectance as a function of cos(theta_d) = dot(wi, wm)."""

    @abc.abstractmethod
    def __call__(self, cos_theta_d: Float[Array, "*batch 1"]) -> Float[Array, "*batch C"]:
        """Reflectance in [0, 1] (dimensionless)."""

    @abc.abstractmethod
    def fittable(self) -> dict[str, ParamSpec]:
        """Fittable parameters: attribute name -> ParamSpec."""


class SchlickFresnel(AbstractFresnel):
    """Schlick's Fresnel approximation with reflectance ``f0`` at normal incidence
    (the "specular albedo" of the foundation model), f0 in [0, 1]."""

    f0: Float[Array, "*batch C"]

    def __init__(self, f0: ArrayLike):
        self.f0 = as_param("SchlickFresnel", "f0", f0, lower=0.0, upper=1.0)

    def __call__(self, cos_theta_d: Float[Array, "*batch 1"]) -> Float[Array, "*batch C"]:
        """f0 + (1 - f0)(1 - cos)^5 (Schlick 1994). See :func:`schlick`."""
        return schlick(cos_theta_d, self.f0)

    def fittable(self) -> dict[str, ParamSpec]:
        """``f0`` in (0, 1) through a sigmoid."""
        return {"f0": ParamSpec(0.0, 1.0, "sigmoid")}


class ConductorFresnel(AbstractFresnel):
    """Exact conductor Fresnel reflectance for complex index ``eta`` + i ``k``
    (eta > 0, k >= 0, per channel) seen from vacuum; see :func:`fresnel_complex`."""

    eta: Float[Array, "*batch C"]
    k: Float[Array, "*batch C"]

    def __init__(self, eta: ArrayLike, k: ArrayLike):
        self.eta = as_param("ConductorFresnel", "eta", eta, lower=0.0, lower_open=True)
        self.k = as_param("ConductorFresnel", "k", k, lower=0.0)

    def __call__(self, cos_theta_d: Float[Array, "*batch 1"]) -> Float[Array, "*batch C"]:
        """Unpolarised reflectance in [0, 1]."""
        return fresnel_conductor(cos_theta_d, self.eta, self.k)

    def fittable(self) -> dict[str, ParamSpec]:
        """``eta`` >= 0.01 and ``k`` >= 0, both through a softplus."""
        # 0.01: below it the model has no measured material (silver's eta ~0.05 at 550 nm).
        return {"eta": ParamSpec(0.01, float("inf"), "softplus"), "k": ParamSpec(0.0, float("inf"), "softplus")}


class DielectricFresnel(AbstractFresnel):
    """Exact dielectric Fresnel reflectance for relative index ``eta`` = eta_t / eta_i > 0;
    see :func:`fresnel_dielectric`."""

    eta: Float[Array, "*batch C"]

    def __init__(self, eta: ArrayLike):
        self.eta = as_param("DielectricFresnel", "eta", eta, lower=0.0, lower_open=True)

    def __call__(self, cos_theta_d: Float[Array, "*batch 1"]) -> Float[Array, "*batch C"]:
        """Unpolarised reflectance in [0, 1]; 1 under total internal reflection."""
        return fresnel_dielectric(cos_theta_d, self.eta)

    def fittable(self) -> dict[str, ParamSpec]:
        """``eta`` in (1, 3) through a sigmoid: the range of real dielectrics seen from air."""
        return {"eta": ParamSpec(1.0, 3.0, "sigmoid")}

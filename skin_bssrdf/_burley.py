"""Normalised diffusion of Christensen & Burley 2015, "Approximate Reflectance
Profiles for Efficient Subsurface Scattering" (Pixar tech. memo 15-04)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._common import AbstractProfile, align, channels, check, radius_arg

# Smallest radius at which the 1/r profile is evaluated, as a fraction of d.
# R(r) ~ A/(4 pi d r) diverges at r = 0 (the energy near 0 is finite: 2 pi r R -> A/(2d)),
# so radial(0) returns the value at this floor instead of Inf; the operator never
# evaluates it there (the sample's own disc uses the closed-form cumulative()).
R_FLOOR_OVER_D = 1e-6

# Albedo-to-scale fits s(A), d = l / s (Christensen & Burley 2015):
SCALE_FITS = {
    # eq. 5, searchlight configuration, l = mean free path 1/sigma_t
    "searchlight": lambda A: 1.85 - A + 7 * jnp.abs(A - 0.8) ** 3,
    # eq. 6, diffuse surface transmission, l = mean free path 1/sigma_t
    "diffuse": lambda A: 1.9 - A + 3.5 * (A - 0.8) ** 2,
    # eq. 8, searchlight with the diffuse mean free path l_d = 1/sigma_tr
    "dmfp": lambda A: 3.5 + 100 * (A - 0.33) ** 4,
}


class Burley(AbstractProfile):
    """Normalised diffusion profile R(r) = A (e^{-r/d} + e^{-r/(3d)}) / (8 pi d r)
    in 1/mm^2 (Christensen & Burley 2015, eqs. 2-3), per channel.

    ``albedo`` A in [0, 1] is the total diffuse reflectance (``total()`` = A
    exactly); ``d`` > 0 the shape length in mm. Use ``from_mean_free_path`` for
    the paper's albedo-to-scale fits.
    """

    albedo: Float[Array, "*pbatch channel"]
    d: Float[Array, "*pbatch channel"]

    def __init__(self, albedo: ArrayLike, d: ArrayLike):
        check("Burley", "albedo", albedo, lo=0.0, hi=1.0)
        check("Burley", "d (shape length, mm)", d, lo=0.0, lo_open=True)
        self.albedo, self.d = channels(albedo, d)

    @classmethod
    def from_mean_free_path(cls, albedo: ArrayLike, mfp: ArrayLike, config: str = "searchlight") -> Burley:
        """Profile with d = mfp / s(A) from one of the paper's fits: ``"searchlight"``
        (eq. 5) or ``"diffuse"`` (eq. 6) with mfp = 1/sigma_t in mm, or ``"dmfp"`` (eq. 8)
        with mfp the diffuse mean free path 1/sigma_tr in mm."""
        if config not in SCALE_FITS:
            raise ValueError(f"Burley.from_mean_free_path: config must be one of {sorted(SCALE_FITS)}, got {config!r}")
        check("Burley.from_mean_free_path", "albedo", albedo, lo=0.0, hi=1.0)
        check("Burley.from_mean_free_path", "mfp (mm)", mfp, lo=0.0, lo_open=True)
        A, l = channels(albedo, mfp)
        return cls(A, l / SCALE_FITS[config](A))

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return self.albedo.shape[:-1]

    def radial(self, r: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch channel"]:
        """R(r) in 1/mm^2 (eq. 2-3); r is floored at 1e-6 d (the profile is 1/r at 0)."""
        r = radius_arg("Burley.radial", r, self.d.dtype)
        return _radial(r, self.albedo, self.d)

    def total(self) -> Float[Array, "*pbatch channel"]:
        """Total diffuse reflectance: A (the profile is normalised, eq. 3)."""
        return self.albedo

    def cumulative(self, r: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch channel"]:
        """A (1 - e^{-r/d}/4 - 3 e^{-r/(3d)}/4), the paper's CDF (eq. 11) times A."""
        r = radius_arg("Burley.cumulative", r, self.d.dtype)
        return _cumulative(r, self.albedo, self.d)


@jax.jit
def _radial(r, A, d):
    r, A, d = align(r, A, d)
    r = jnp.maximum(r, R_FLOOR_OVER_D * d)
    return A * (jnp.exp(-r / d) + jnp.exp(-r / (3 * d))) / (8 * jnp.pi * d * r)


@jax.jit
def _cumulative(r, A, d):
    r, A, d = align(r, A, d)
    return A * (1 - 0.25 * jnp.exp(-r / d) - 0.75 * jnp.exp(-r / (3 * d)))

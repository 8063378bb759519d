"""Multipole for thin slabs, Donner & Jensen 2005, "Light Diffusion in
Multi-Layered Translucent Materials" (SIGGRAPH 2005), section 3 (eqs. 8-11).

One homogeneous slab of thickness ``thickness`` (mm) with its own index
mismatch at the top and bottom. The dipole is mirrored about both extrapolated
boundaries: 2 n + 1 source pairs at

    z_{r,i} = 2 i (d + z_b0 + z_bd) + z_r,   z_{v,i} = 2 i (d + z_b0 + z_bd) - z_r - 2 z_b0,

i = -n..n, with z_b = 2 A D, D = 1/(3 sigma_t'), A from Jensen's F_dr fit per
boundary. Reflectance and transmittance profiles are the truncated sums;
``total()`` / ``total_transmittance()`` are the exact integrals of those
truncated sums (closed forms, so the quadrature test is exact), and
``total_untruncated()`` is the n -> infinity limit, the 1-D diffusion solution
of the slab. Their difference is the truncation error of the profiles, which
``truncation()`` reports; it shrinks like exp(-2 n sigma_tr (d + z_b0 + z_bd)),
so weakly absorbing slabs need more pairs.

Not done: combining several slabs (Donner & Jensen's Kubelka-Munk convolution
of layer profiles in frequency space, section 4). It needs Hankel transforms of
each layer's R and T on a radial grid; the single-slab profile here is the
building block, but a layered skin model to the standard of the other profiles
(closed-form totals, exact quadrature checks) was out of this package's scope.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from brdf import safe_sqrt

from ._common import ETA_MAX, ETA_MIN, AbstractProfile, align, channels, check, fresnel_diffuse_reflectance, radius_arg
from ._dipole import check_coefficients, dipole_term, dipole_term_cumulative


class Multipole(AbstractProfile):
    """Multipole slab profile (Donner & Jensen 2005, eqs. 8-11), per channel.

    ``sigma_a``, ``sigma_s_prime`` (1/mm), ``thickness`` d > 0 (mm), ``eta`` the
    slab's index relative to the medium above, ``eta_bottom`` relative to the
    medium below (both in [1, 3]); ``n_pairs`` (static) mirrored pairs on each
    side of the central dipole. ``radial`` is the reflectance profile R(r),
    ``transmittance`` the profile T(r) at the bottom face, both in 1/mm^2.
    The slab must be thicker than one transport mean free path 1/sigma_t'
    (where the real source sits).
    """

    sigma_a: Float[Array, "*pbatch channel"]
    sigma_s_prime: Float[Array, "*pbatch channel"]
    thickness: Float[Array, "*pbatch channel"]
    eta: Float[Array, "*pbatch channel"]
    eta_bottom: Float[Array, "*pbatch channel"]
    n_pairs: int = eqx.field(static=True)

    def __init__(
        self,
        sigma_a: ArrayLike,
        sigma_s_prime: ArrayLike,
        thickness: ArrayLike,
        eta: ArrayLike = 1.3,
        eta_bottom: ArrayLike = 1.3,
        n_pairs: int = 20,
    ):
        check_coefficients("Multipole", sigma_a, sigma_s_prime, eta)
        check("Multipole", "thickness (mm)", thickness, lo=0.0, lo_open=True)
        check("Multipole", "eta_bottom", eta_bottom, lo=ETA_MIN, hi=ETA_MAX)
        # The real source sits at z_r = 1/sigma_t'; below the bottom face the image
        # construction (and diffusion itself) no longer describes the slab.
        check("Multipole", "thickness - 1/(sigma_a + sigma_s_prime) (slab thinner than a transport mean free path)",
              jnp.asarray(thickness) - 1 / (jnp.asarray(sigma_a) + jnp.asarray(sigma_s_prime)), lo=0.0, lo_open=True)
        if not isinstance(n_pairs, int) or n_pairs < 0:
            raise ValueError(f"Multipole: n_pairs must be an int >= 0, got {n_pairs!r}")
        self.sigma_a, self.sigma_s_prime, self.thickness, self.eta, self.eta_bottom = channels(
            sigma_a, sigma_s_prime, thickness, eta, eta_bottom
        )
        self.n_pairs = n_pairs

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return self.sigma_a.shape[:-1]

    def _params(self):
        return self.sigma_a, self.sigma_s_prime, self.thickness, self.eta, self.eta_bottom

    def radial(self, r: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch channel"]:
        """Reflectance R(r) in 1/mm^2 (eq. 10): alpha'/(4 pi) sum_i [z_{r,i}(1 + s d_{r,i}) e^{-s d_{r,i}}/d_{r,i}^3
        - z_{v,i}(1 + s d_{v,i}) e^{-s d_{v,i}}/d_{v,i}^3]; r in mm, [...] -> [..., C]."""
        r = radius_arg("Multipole.radial", r, self.sigma_a.dtype)
        return _profile(r, *self._params(), n=self.n_pairs, bottom=False, cumulative=False)

    def transmittance(self, r: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch channel"]:
        """Transmittance T(r) in 1/mm^2 at the bottom face (eq. 11), the same sum with depths d - z."""
        r = radius_arg("Multipole.transmittance", r, self.sigma_a.dtype)
        return _profile(r, *self._params(), n=self.n_pairs, bottom=True, cumulative=False)

    def cumulative(self, r: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch channel"]:
        """Reflected energy within radius r (mm), closed form term by term."""
        r = radius_arg("Multipole.cumulative", r, self.sigma_a.dtype)
        return _profile(r, *self._params(), n=self.n_pairs, bottom=False, cumulative=True)

    def total(self) -> Float[Array, "*pbatch channel"]:
        """Integral of 2 pi r R(r) of the truncated sum:
        alpha'/2 sum_i [sgn(z_{r,i}) e^{-s|z_{r,i}|} - sgn(z_{v,i}) e^{-s|z_{v,i}|}]."""
        return _totals(*self._params(), n=self.n_pairs)[0]

    def total_transmittance(self) -> Float[Array, "*pbatch channel"]:
        """Integral of 2 pi r T(r) of the truncated sum."""
        return _totals(*self._params(), n=self.n_pairs)[1]

    def total_untruncated(self) -> tuple[Array, Array]:
        """(R, T) totals of the infinite multipole, i.e. the 1-D diffusion solution of the slab
        with extrapolated boundaries at -z_b0 and d + z_bd and the source at z_r:
        R = alpha' cosh(s z_b0) sinh(s (L - z_r - z_b0)) / sinh(s L),
        T = alpha' sinh(s (z_r + z_b0)) cosh(s z_bd) / sinh(s L), L = d + z_b0 + z_bd."""
        return _totals_exact(*self._params())

    def truncation(self) -> Float[Array, "*pbatch channel"]:
        """|total() - total_untruncated()[0]| + same for T: the energy the truncated sums misplace."""
        R, T = _totals(*self._params(), n=self.n_pairs)
        R0, T0 = _totals_exact(*self._params())
        return jnp.abs(R - R0) + jnp.abs(T - T0)


def _geometry(sigma_a, sigma_s_prime, thickness, eta, eta_bottom):
    st = sigma_a + sigma_s_prime
    D = 1 / (3 * st)
    f0, fd = fresnel_diffuse_reflectance(eta), fresnel_diffuse_reflectance(eta_bottom)
    zb0 = 2 * D * (1 + f0) / (1 - f0)
    zbd = 2 * D * (1 + fd) / (1 - fd)
    s = safe_sqrt(3 * sigma_a * st)  # zero (finite) gradient at sigma_a = 0
    return sigma_s_prime / st, s, 1 / st, zb0, zbd


def _depths(zr, zb0, zbd, d, n, dtype):
    i = jnp.arange(-n, n + 1, dtype=dtype)
    i = i.reshape((2 * n + 1,) + (1,) * zr.ndim)
    period = (2 * (d + zb0 + zbd))[None]
    return i * period + zr[None], i * period - zr[None] - 2 * zb0[None]  # [2n+1, ...]


def _totals(sigma_a, sigma_s_prime, thickness, eta, eta_bottom, *, n):
    a, s, zr, zb0, zbd = _geometry(sigma_a, sigma_s_prime, thickness, eta, eta_bottom)
    zri, zvi = _depths(zr, zb0, zbd, thickness, n, sigma_a.dtype)

    def signed(z):
        return jnp.sign(z) * jnp.exp(-s[None] * jnp.abs(z))

    d = thickness[None]
    R = 0.5 * a * jnp.sum(signed(zri) - signed(zvi), axis=0)
    T = 0.5 * a * jnp.sum(signed(d - zri) - signed(d - zvi), axis=0)
    return R, T


_totals = jax.jit(_totals, static_argnames="n")


@jax.jit
def _totals_exact(sigma_a, sigma_s_prime, thickness, eta, eta_bottom):
    a, s, zr, zb0, zbd = _geometry(sigma_a, sigma_s_prime, thickness, eta, eta_bottom)
    L = thickness + zb0 + zbd
    # sinh(s x)/sinh(s L) written with exponentials of non-positive arguments (no overflow
    # for thick slabs) and continued to x/L at s = 0 (no absorption).
    def ratio(x):
        num = -jnp.expm1(-2 * s * x)
        den = -jnp.expm1(-2 * s * L)
        ok = den > 1e-12
        lin = x / L
        return jnp.where(ok, jnp.exp(-s * (L - x)) * num / jnp.where(ok, den, 1.0), lin)

    R = a * jnp.cosh(s * zb0) * ratio(L - zr - zb0)
    T = a * jnp.cosh(s * zbd) * ratio(zr + zb0)
    return R, T


def _profile(r, sigma_a, sigma_s_prime, thickness, eta, eta_bottom, *, n, bottom, cumulative):
    a, s, zr, zb0, zbd = _geometry(sigma_a, sigma_s_prime, thickness, eta, eta_bottom)
    r, a, s, zr, zb0, zbd, d = align(r, a, s, zr, zb0, zbd, thickness)
    zri, zvi = _depths(zr, zb0, zbd, d, n, sigma_a.dtype)  # [2n+1, ...]
    if bottom:
        zri, zvi = d[None] - zri, d[None] - zvi
    term = dipole_term_cumulative if cumulative else dipole_term
    out = jnp.sum(term(r[None], zri, s[None]) - term(r[None], zvi, s[None]), axis=0)
    return a / (4 * jnp.pi) * out


_profile = jax.jit(_profile, static_argnames=("n", "bottom", "cumulative"))

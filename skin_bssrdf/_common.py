"""Shared pieces of the profiles: the abstract profile, parameter checks,
rank-explicit broadcasting and the diffuse Fresnel terms.

The tests run with ``jax_numpy_rank_promotion="raise"``, so every broadcast
between arrays of different rank is made explicit here (``align``) instead of
relying on NumPy's implicit rank promotion.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from brdf import safe_div, widest_float

# Range of relative index of refraction (medium / outside) the dipole family
# accepts. Below 1 the medium is optically thinner than the outside and Jensen's
# F_dr polynomial turns negative (it was fitted for eta >= 1); above 3 no
# tissue or common material lives and the polynomial is extrapolated.
ETA_MIN = 1.0
ETA_MAX = 3.0


def concrete(x) -> np.ndarray | None:
    """The value of ``x`` as NumPy when it is concrete, ``None`` under a trace.

    Checks that raise ``ValueError`` run only on concrete values, never on
    tracers (a jitted fitter must not trip over a value it cannot see).
    """
    leaves = jax.tree_util.tree_leaves(x)
    if any(isinstance(leaf, jax.core.Tracer) for leaf in leaves):
        return None
    return np.asarray(x)


def check(owner: str, name: str, x, *, lo=None, hi=None, lo_open=False, hi_open=False):
    """Raise ``ValueError`` naming ``owner.name`` when concrete ``x`` is non-finite or out of range."""
    v = concrete(x)
    if v is None:
        return
    if v.size and not np.all(np.isfinite(v)):
        raise ValueError(f"{owner}: {name} must be finite, got {v!r}")
    if lo is not None and v.size:
        bad = v <= lo if lo_open else v < lo
        if np.any(bad):
            rel = ">" if lo_open else ">="
            raise ValueError(f"{owner}: {name} must be {rel} {lo}, got min {v.min()!r}")
    if hi is not None and v.size:
        bad = v >= hi if hi_open else v > hi
        if np.any(bad):
            rel = "<" if hi_open else "<="
            raise ValueError(f"{owner}: {name} must be {rel} {hi}, got max {v.max()!r}")


def as_float(x) -> Array:
    """``x`` as a floating JAX array (integers become the default float)."""
    x = jnp.asarray(x)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    return x


def cast_floats(tree, dtype):
    """Every floating array leaf of ``tree`` (a profile, a tuple of arrays) cast to ``dtype``."""

    def cast(x):
        return x.astype(dtype) if eqx.is_inexact_array(x) and x.dtype != dtype else x

    return jax.tree_util.tree_map(cast, tree)


def channels(*xs) -> tuple[Array, ...]:
    """Broadcast parameters to one common shape ``[..., C]`` (scalars become ``[1]``) and one dtype
    (:func:`brdf.widest_float`)."""
    xs = [as_float(x) for x in xs]
    dtype = widest_float(*xs)
    shape = jnp.broadcast_shapes(*(x.shape for x in xs))
    if len(shape) == 0:
        shape = (1,)
    return tuple(jnp.broadcast_to(align_to(x, len(shape)), shape).astype(dtype) for x in xs)


def align_to(x: Array, ndim: int) -> Array:
    """Prepend unit axes so ``x`` has rank ``ndim`` (explicit rank promotion)."""
    return jnp.reshape(x, (1,) * (ndim - x.ndim) + x.shape)


def align(*xs) -> tuple[Array, ...]:
    """Give all arrays the same rank by prepending unit axes (NumPy semantics, made explicit)."""
    xs = [jnp.asarray(x) for x in xs]
    n = max(x.ndim for x in xs)
    return tuple(align_to(x, n) for x in xs)


def radius_arg(owner: str, r: ArrayLike, dtype) -> Array:
    """Validate a radius array and return ``r[..., None]`` (a channel axis for broadcasting), cast to the
    profile's ``dtype``: a profile is evaluated in its parameters' precision, whatever the radii's."""
    check(owner, "r (radius, mm)", r, lo=0.0)
    r = as_float(r).astype(dtype)
    return r[..., None]


class AbstractProfile(eqx.Module):
    """A radially symmetric diffuse reflectance profile R_d(r), per colour channel.

    Lengths are in mm. ``radial(r)`` is the exitance at distance r from a unit
    power point of incidence, in 1/mm^2 (so ``2 pi r radial(r)`` integrates to
    the total diffuse reflectance). Parameters broadcast to ``[..., C]``;
    ``radial`` of ``r [...]`` returns the NumPy broadcast of ``r[..., None]``
    with the parameters, i.e. ``[..., C]``.
    """

    @property
    @abc.abstractmethod
    def batch_shape(self) -> tuple[int, ...]:
        """Parameter batch shape: the axes before the profile's own parameter axes."""

    @abc.abstractmethod
    def radial(self, r: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch channel"]:
        """R_d(r) in 1/mm^2 at distance r (mm) from the point of incidence."""

    @abc.abstractmethod
    def total(self) -> Float[Array, "*pbatch channel"]:
        """Total diffuse reflectance: the integral of 2 pi r R_d(r) over r in [0, inf)."""

    @abc.abstractmethod
    def cumulative(self, r: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch channel"]:
        """Energy within radius r: the integral of 2 pi s R_d(s) over s in [0, r] (closed form)."""

    def tail(self, r: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch channel"]:
        """Energy beyond radius r: ``total() - cumulative(r)`` (what truncating at r loses)."""
        c = self.cumulative(r)
        t = self.total()
        c, t = align(c, t)
        return t - c


# --- diffuse Fresnel terms ----------------------------------------------------


@jax.jit
def _fdr(eta):
    return -1.440 / eta**2 + 0.710 / eta + 0.668 + 0.0636 * eta


def fresnel_diffuse_reflectance(eta: ArrayLike) -> Array:
    """Internal diffuse Fresnel reflectance F_dr(eta) = -1.440/eta^2 + 0.710/eta + 0.668 + 0.0636 eta.

    Args:
        eta: relative refractive index (>= 1).

    Returns:
        F_dr, the shape of ``eta``.

    References:
        Jensen et al. 2001, "A practical model for subsurface light transport", the equation after eq. 4 (the
        polynomial fit of Egan & Hilgeman 1979).
    """
    return _fdr(as_float(eta))


def fresnel_dielectric(cos_i: Array, eta: Array) -> Array:
    """Unpolarised Fresnel reflectance for light travelling inside a medium of relative
    index eta (>= 1) towards the boundary, cosine ``cos_i`` inside. 1 beyond the critical angle."""
    sin2_t = eta**2 * (1 - cos_i**2)
    tir = sin2_t >= 1
    cos_t = jnp.sqrt(jnp.where(tir, 0.5, 1 - jnp.where(tir, 0.5, sin2_t)))
    # inside index eta, outside 1
    rs = safe_div(eta * cos_i - cos_t, eta * cos_i + cos_t)
    rp = safe_div(cos_i - eta * cos_t, cos_i + eta * cos_t)
    return jnp.where(tir, 1.0, 0.5 * (rs**2 + rp**2))


# Gauss-Legendre nodes for the Fresnel moments. The integrand is smooth in the
# transmitted cosine (see fresnel_moments), so 32 nodes reach float64 rounding.
_GL_X, _GL_W = np.polynomial.legendre.leggauss(32)


def fresnel_moments(eta: ArrayLike) -> tuple[Array, Array]:
    """Fresnel moments C_i = integral_0^1 F_r(eta, mu) mu^i dmu, i = 1, 2, seen from inside a medium.

    Computed by quadrature, not a fit: total internal reflection (F = 1) is integrated in closed form below the
    critical cosine mu_c = sqrt(1 - 1/eta^2); above it the substitution mu_t = cos(transmitted angle),
    mu dmu = mu_t dmu_t / eta^2, makes the integrand smooth, so Gauss-Legendre converges exponentially and the
    result is differentiable in eta. 2 C_1 is F_dr.

    Args:
        eta: relative refractive index (>= 1).

    Returns:
        (C_1, C_2), each the shape of ``eta``.

    References:
        d'Eon 2012, "A better dipole", eq. 8; pbrt-v3, sec. 15.5.
    """
    return _fresnel_moments(as_float(eta))


@jax.jit
def _fresnel_moments(eta):
    mu_c2 = jnp.clip(1 - 1 / eta**2, 0, 1)
    mu_c = jnp.where(mu_c2 > 0, jnp.sqrt(jnp.where(mu_c2 > 0, mu_c2, 1)), 0)
    x = jnp.asarray(0.5 * (_GL_X + 1), eta.dtype)  # mu_t nodes on (0, 1)
    w = jnp.asarray(0.5 * _GL_W, eta.dtype)
    e = eta[..., None]
    mu_t = align_to(x, e.ndim)
    mu = jnp.sqrt(1 - (1 - mu_t**2) / e**2)  # >= mu_c > 0 on the open interval
    f = _fresnel_pair(mu, mu_t, e)
    jac = mu_t / e**2  # mu dmu = mu_t dmu_t / eta^2
    ww = align_to(w, e.ndim)
    c1 = mu_c2 / 2 + jnp.sum(ww * f * jac, axis=-1)
    c2 = mu_c**3 / 3 + jnp.sum(ww * f * mu * jac, axis=-1)
    return c1, c2


def _fresnel_pair(cos_i, cos_t, eta):
    rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    rp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    return 0.5 * (rs**2 + rp**2)


def one_minus_exp_over(x: Array) -> Array:
    """(1 - e^{-x}) / x, continued by 1 at x = 0 with a finite gradient (double where).

    Used where a difference of exponentials is divided by sigma_tr, which is 0
    when nothing is absorbed (albedo 1)."""
    small = jnp.abs(x) < 1e-6
    xs = jnp.where(small, 1.0, x)
    # Taylor series 1 - x/2 + x^2/6 below the switch: error < 1e-18 there.
    return jnp.where(small, 1 - x / 2 + x * x / 6, -jnp.expm1(-xs) / xs)

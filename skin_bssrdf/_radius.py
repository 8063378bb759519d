"""Radius within which a profile holds a given fraction of its energy."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._common import AbstractProfile, check

# Bracket of the bisection (mm): from a micron to ten metres covers every
# material the library models; 80 halvings in log-radius reach float64 rounding.
_R_LO, _R_HI, _STEPS = 1e-3, 1e4, 80


def energy_radius(profile: AbstractProfile, fraction: float = 0.99) -> Float[Array, "*pbatch channel"]:
    """Radius (mm) inside which a profile holds ``fraction`` of its total diffuse reflectance, per channel.

    Bisection in log r on the closed-form cumulative energy: cumulative(r) = fraction x total(). Use it to choose
    the diffusion operator's neighbour radius (the tail beyond it is 1 - fraction).

    Args:
        profile: a radial diffusion profile (``Dipole``, ``Burley``, ...).
        fraction: the share of the total energy inside the radius, in (0, 1).

    Returns:
        The radius in mm, [*pbatch, C]: one per profile and channel.
    """
    check("energy_radius", "fraction", fraction, lo=0.0, hi=1.0, lo_open=True, hi_open=True)
    return _bisect(profile, fraction)


@eqx.filter_jit
def _bisect(profile, fraction):
    """:func:`energy_radius`' bisection as one program (called eagerly, a fresh ``fori_loop`` body was
    traced and compiled again on every call)."""
    total = profile.total()

    def body(_, bounds):
        lo, hi = bounds
        mid = jnp.sqrt(lo * hi)
        below = _cum(profile, mid)
        inside = below < fraction * total
        return jnp.where(inside, mid, lo), jnp.where(inside, hi, mid)

    lo = jnp.full(total.shape, _R_LO, total.dtype)
    hi = jnp.full(total.shape, _R_HI, total.dtype)
    lo, hi = jax.lax.fori_loop(0, _STEPS, body, (lo, hi))
    return jnp.sqrt(lo * hi)


def _cum(profile, r):
    """cumulative at per-channel radii r [*pbatch, C] -> [*pbatch, C], one channel at a time."""
    return jnp.stack([profile.cumulative(r[..., c])[..., c] for c in range(r.shape[-1])], axis=-1)


# The one rule for the diffusion operator's neighbour radius, used by every caller that builds an operator
# (stage simulation, the fitter, the renderer, the demo): the radius holding this fraction of the profile's
# energy, at the widest sample that scatters. The 1% beyond it is dropped (DiffusionOperator.tail reports it).
OPERATOR_ENERGY = 0.99
# Smallest radius (mm): a micron, below any texel, so an operator always has the sample's own disc.
MIN_OPERATOR_RADIUS_MM = 1e-3


def operator_radius(profile: AbstractProfile, where=None, fraction: float = OPERATOR_ENERGY) -> float:
    """The diffusion operator's neighbour radius for ``profile`` (mm).

    Args:
        profile: a diffusion profile with per-sample parameters, batch [P, C] (or [C]).
        where: optional boolean [P]: the samples that scatter; the others are ignored.
        fraction: the energy fraction inside the radius (default ``OPERATOR_ENERGY``, 0.99).

    Returns:
        The largest :func:`energy_radius` over the chosen samples and channels, floored at
        ``MIN_OPERATOR_RADIUS_MM``; the floor when no sample scatters.
    """
    import numpy as np

    r = np.asarray(energy_radius(profile, fraction), np.float64)
    if where is not None:
        sel = np.asarray(where, bool).reshape(-1)
        r = r.reshape(sel.shape[0], -1)[sel]
    r = r[np.isfinite(r)]
    return max(float(np.max(r)) if r.size else MIN_OPERATOR_RADIUS_MM, MIN_OPERATOR_RADIUS_MM)


def widest_operator_radius(mfp_max_mm: float, fraction: float = OPERATOR_ENERGY) -> float:
    """The operator radius (mm) that covers every Christensen-Burley profile (diffuse mean free
    path parametrisation, "dmfp") with a mean free path up to ``mfp_max_mm``, whatever its albedo.

    The profile's normalised shape depends only on d = mfp / s(A), and s(A) = 3.5 + 100 (A - 0.33)^4
    is smallest (3.5) at A = 0.33, so that albedo gives the widest profile. Used where the profiles
    are not known yet (the fitter searching mean free paths up to a bound).

    Args:
        mfp_max_mm: the largest diffuse mean free path (mm), > 0.
        fraction: the energy fraction inside the radius.

    Returns:
        The radius in mm.

    References:
        Christensen & Burley 2015, "Approximate Reflectance Profiles for Efficient Subsurface
        Scattering", eq. 8 (the dmfp scale fit) and eq. 11 (the CDF).
    """
    from ._burley import Burley

    check("widest_operator_radius", "mfp_max_mm", mfp_max_mm, lo=0.0, lo_open=True)
    return operator_radius(Burley.from_mean_free_path(jnp.asarray([0.33]), jnp.asarray([float(mfp_max_mm)]),
                                                      config="dmfp"), fraction=fraction)

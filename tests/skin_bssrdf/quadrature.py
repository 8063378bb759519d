"""Independent radial quadrature for the profile tests: composite Gauss-Legendre
on geometric panels, so both the sharp peak near r = 0 (width ~ 1/sigma_t') and
the long exponential tail are resolved. Does not use the profiles' closed forms."""

import jax.numpy as jnp
import numpy as np

_X, _W = np.polynomial.legendre.leggauss(24)


def nodes(r_min=1e-7, r_max=1e3, panels=120):
    """Nodes and weights on [0, r_max]: one panel [0, r_min] then geometric panels."""
    edges = np.concatenate([[0.0], np.geomspace(r_min, r_max, panels)])
    a, b = edges[:-1, None], edges[1:, None]
    r = 0.5 * (b - a) * _X[None, :] + 0.5 * (a + b)
    w = 0.5 * (b - a) * _W[None, :]
    return r.ravel(), w.ravel()


def integrate_disc(profile, r_max=1e3):
    """integral_0^r_max 2 pi r R_d(r) dr by quadrature, per channel: [..., C]."""
    r, w = nodes(r_max=r_max)
    vals = profile.radial(jnp.asarray(r))  # [N, ..., C] only if params are [C]
    return jnp.sum(jnp.asarray(2 * np.pi * r * w)[:, None] * vals, axis=0)

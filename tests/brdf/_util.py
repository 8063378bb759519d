"""Direction helpers shared by the brdf tests, and the jitted evaluators (tests.helpers.fjit)."""

import jax
import jax.numpy as jnp
import numpy as np

import brdf
from tests.helpers import fjit


def sph(theta, phi, dtype=jnp.float64):
    """Unit vectors [..., 3] from polar angle theta and azimuth phi (radians)."""
    theta = np.asarray(theta, float)
    phi = np.asarray(phi, float)
    theta, phi = np.broadcast_arrays(theta, phi)
    v = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)
    return jnp.asarray(v, dtype)


def from_cos(c, phi, dtype=jnp.float64):
    """Unit vectors [..., 3] from cos(theta) (may be exactly 0 or tiny) and azimuth."""
    c = np.asarray(c, float)
    phi = np.asarray(phi, float)
    c, phi = np.broadcast_arrays(c, phi)
    s = np.sqrt(np.maximum(1 - c * c, 0))
    return jnp.asarray(np.stack([s * np.cos(phi), s * np.sin(phi), c], -1), dtype)


def edge_directions(dtype=jnp.float64):
    """Pairs [N, 3] covering the edges every model must survive: grazing (cos = 1e-7 and
    exactly 0) on either side, wi = wo, mirror pairs, normal incidence, below horizon."""
    cs = [1e-7, 0.0, 1.0, 0.5, 1e-7, 0.3]
    pairs_i, pairs_o = [], []
    for ci in cs:
        for co in cs:
            for dphi in (0.0, np.pi, 1.0):
                pairs_i.append((ci, 0.3))
                pairs_o.append((co, 0.3 + dphi))
    wi = from_cos([p[0] for p in pairs_i], [p[1] for p in pairs_i], dtype)
    wo = from_cos([p[0] for p in pairs_o], [p[1] for p in pairs_o], dtype)
    below = jnp.asarray([[0.6, 0.0, -0.8], [0.0, 0.0, -1.0]], dtype)
    up = jnp.asarray([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]], dtype)
    return jnp.concatenate([wi, below, up]), jnp.concatenate([wo, up, below])


@fjit
def ev(m, wi, wo):
    """model(wi, wo) on batched directions, compiled once per model structure."""
    return m(wi, wo)


@fjit
def ev_pairs(m, wi, wo):
    """One material (0-d or [C] parameters) over [N, 3] pairs."""
    return jax.vmap(m)(wi, wo)


@fjit(static_argnums=(1, 2))
def edge_case_pairs(key, n, dtype=jnp.float64):
    """brdf.check.edge_case_pairs as one compiled program: called eagerly it runs
    some thirty small ops, each compiled again for every new n and dtype (seconds)."""
    return brdf.check.edge_case_pairs(key, n, dtype)


@fjit(static_argnums=(1, 2))
def example_models(key, n, dtype=jnp.float64):
    """brdf.check.example_models as one compiled program (eager, it compiles every op)."""
    return brdf.check.example_models(key, n, dtype)

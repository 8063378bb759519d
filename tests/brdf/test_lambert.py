"""Lambert: closed form, albedo, horizon, validation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdf
from tests.brdf._util import edge_directions, ev, ev_pairs, fjit, sph
from tests.helpers import REFUSED, assert_close, assert_finite


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_closed_form(dtype):
    albedo = jnp.asarray([[0.2, 0.5, 0.9]], dtype)
    m = brdf.Lambert(albedo)
    wi = sph([0.1, 0.7, 1.5], [0.0, 1.0, 2.0], dtype)
    wo = sph([0.3, 1.2, 0.0], [3.0, 0.5, 0.0], dtype)
    f = ev(m, wi, wo)
    assert f.shape == (3, 3) and f.dtype == dtype
    assert_close(f, jnp.broadcast_to(albedo / np.pi, (3, 3)), dtype)


def test_zero_below_horizon_and_finite_edges():
    m = brdf.Lambert(jnp.asarray([0.5, 0.6, 0.7]))
    wi, wo = edge_directions()
    f = ev_pairs(m, wi, wo)
    active = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    assert_close(f[~active], 0.0)
    assert_close(f[active], jnp.broadcast_to(jnp.asarray([0.5, 0.6, 0.7]) / np.pi, f[active].shape))
    g = fjit(jax.grad(lambda a: jnp.sum(jax.vmap(brdf.Lambert(a))(wi, wo))))(jnp.asarray([0.5, 0.6, 0.7]))
    assert_finite(g)


def test_albedo_equals_parameter():
    # White furnace: the directional albedo is the parameter itself, for any wo.
    m = brdf.Lambert(jnp.asarray([0.25, 1.0]))
    a = brdf.check.directional_albedo(m, sph([0.0, 0.8, 1.5], [0.0, 0.0, 2.0]), n_theta=16, n_phi=8)
    assert_close(a, jnp.broadcast_to(jnp.asarray([0.25, 1.0]), (3, 2)), rtol=1e-12)


def test_negative_albedo_raises():
    with pytest.raises(ValueError, match="albedo"):
        brdf.Lambert(jnp.asarray([0.5, -0.1, 0.2]))
    with pytest.raises(ValueError, match="albedo"):
        brdf.Lambert(jnp.nan)


def test_rank_mismatch_raises():
    m = brdf.Lambert(jnp.full((4, 3), 0.5))
    with pytest.raises(ValueError, match="rank"):
        m(jnp.zeros((2, 4, 3)).at[..., 2].set(1), jnp.zeros((2, 4, 3)).at[..., 2].set(1))
    # [4, 2] directions also break the "*batch 3" annotation: the test-time checker refuses them first.
    with pytest.raises(REFUSED, match=r"\[\*batch, 3\]|'wi'"):
        m(jnp.zeros((4, 2)), jnp.zeros((4, 2)))

"""brdf.check on models whose answers are known, including models built to fail."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jaxtyping import Array, Float

import brdf
from tests.brdf._util import edge_case_pairs, from_cos
from tests.helpers import REFUSED, assert_close


class _Unguarded(brdf.AbstractBRDF):
    """A model written carelessly: sqrt of the cosines without a guard (NaN
    gradient at cos = 0) and a negative lobe. The checks must catch both."""

    k: Float[Array, ""]

    def __call__(self, wi, wo):
        c = wi[..., 2:3] * wo[..., 2:3]
        return self.k * jnp.sqrt(jnp.maximum(c, 0.0)) - 0.1 * wi[..., 0:1]

    def fittable(self):
        return {}


def test_quadrature_weights():
    dirs, w = brdf.check.hemisphere_quadrature(8, 16)
    assert_close(jnp.sum(w), 2 * np.pi, rtol=1e-13)  # solid angle of the hemisphere
    assert_close(jnp.sum(w * dirs[:, 2]), np.pi, rtol=1e-13)  # projected solid angle
    assert_close(jnp.linalg.norm(dirs, axis=-1), 1.0, atol=1e-14)


def test_albedo_of_lambert_by_quadrature_and_mc(key):
    m = brdf.Lambert(jnp.asarray([0.3, 0.9]))
    wo = from_cos([1.0, 0.5, 0.01], [0.0, 1.0, 2.0])
    expected = jnp.broadcast_to(jnp.asarray([0.3, 0.9]), (3, 2))
    assert_close(brdf.check.directional_albedo(m, wo, 8, 8), expected, rtol=1e-12)
    # Cosine sampling is exact for Lambert: every sample's estimate is the albedo.
    mc, se = brdf.check.directional_albedo_mc(m, wo, key, n=256, sampler="cosine")
    assert_close(mc, jnp.broadcast_to(jnp.asarray([0.3, 0.9]), (3, 2)), rtol=1e-12)
    assert float(jnp.max(se)) < 1e-12
    amax, _ = brdf.check.max_albedo(m, n_incident=4, n_theta=8, n_phi=8)
    assert_close(amax, 0.9, rtol=1e-12)


def test_checks_catch_a_bad_model(key):
    wi, wo = edge_case_pairs(key, 512)
    bad = _Unguarded(jnp.asarray(1.0))
    report = brdf.check.stability(bad, wi, wo)
    assert report["value"] and not report["grad_directions"] and not report["nonnegative"]
    assert float(brdf.check.min_value(bad, wi, wo)) < 0
    good = brdf.check.stability(brdf.Lambert(jnp.ones(3) * 0.5), wi, wo)
    assert all(good.values())


def test_reciprocity_error_separates_models(key):
    wi, wo = brdf.check.random_pairs(key, 256)
    assert float(brdf.check.reciprocity_error(brdf.Lambert(0.5), wi, wo)) == 0.0
    assert float(brdf.check.reciprocity_error(brdf.Phong(0.0, 1.0, 5.0), wi, wo)) > 0.1


def test_bad_arguments_raise():
    m = brdf.Lambert(0.5)
    with pytest.raises(ValueError, match="over"):
        brdf.check.directional_albedo(m, jnp.asarray([0.0, 0.0, 1.0]), over="both")
    with pytest.raises(ValueError, match="sampler"):
        brdf.check.directional_albedo_mc(m, jnp.asarray([0.0, 0.0, 1.0]), jax.random.PRNGKey(0), sampler="ggx")
    with pytest.raises(ValueError, match="n_theta"):
        brdf.check.hemisphere_quadrature(0, 4)
    # [2, 2] directions also break directional_albedo's annotation: the test-time checker refuses them first.
    with pytest.raises(REFUSED, match="directions|'w'"):
        brdf.check.directional_albedo(m, jnp.zeros((2, 2)))

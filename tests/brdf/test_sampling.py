"""Sampling routines against their densities: pdfs integrate to 1 and sample
averages match pdf-weighted quadrature."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdf
from tests.brdf._util import fjit, sph
from tests.helpers import assert_close

N = 1 << 16


def _moments(w):
    """Test functions of a direction: z, z^2, x, x*y, x^2 (mean over samples or weights)."""
    x, y, z = w[..., 0], w[..., 1], w[..., 2]
    return jnp.stack([z, z * z, x, x * y, x * x], -1)


def test_cosine_hemisphere(key):
    u = jax.random.uniform(key, (N, 2))
    w = fjit(brdf.sample_cosine_hemisphere)(u)
    assert_close(jnp.linalg.norm(w, axis=-1), 1.0, atol=1e-12)
    assert float(jnp.min(w[:, 2])) >= 0
    dirs, wt = brdf.check.hemisphere_quadrature(16, 32)
    pdf = fjit(brdf.pdf_cosine_hemisphere)(dirs)[:, 0]
    assert_close(jnp.sum(pdf * wt), 1.0, rtol=1e-12)
    expect = jnp.sum(_moments(dirs) * (pdf * wt)[:, None], 0)
    got = jnp.mean(_moments(w), 0)
    se = jnp.std(_moments(w), 0) / np.sqrt(N)
    assert np.all(np.abs(np.asarray(got - expect)) < 5 * np.asarray(se) + 1e-12)  # 5 sigma


@pytest.mark.parametrize(
    "dist", [brdf.GGX(0.3), brdf.GGX(0.6, 0.15), brdf.Beckmann(0.3), brdf.Beckmann(0.5, 0.2)], ids=str
)
def test_microfacet_normal_sampling(dist, key):
    # The density of sample_wm(wo, .) is pdf_wm(wo, .): visible normals for GGX
    # (Heitz 2018), D cos for Beckmann. It integrates to 1 and reproduces moments.
    dirs, wt = brdf.check.hemisphere_quadrature(48, 96, breaks=(0.1, 0.3, 0.6, 1.0))
    for wo in (sph(0.0, 0.0), sph(1.0, 0.4), sph(1.5, 2.0)):
        pdf = fjit(lambda d, a, b: d.pdf_wm(a, b))(dist, jnp.broadcast_to(wo, dirs.shape), dirs)[:, 0]
        assert abs(float(jnp.sum(pdf * wt)) - 1.0) < 1e-4
        u = jax.random.uniform(key, (N, 2))
        wm = fjit(lambda d, a, b: d.sample_wm(a, b))(dist, jnp.broadcast_to(wo, (N, 3)), u)
        assert_close(jnp.linalg.norm(wm, axis=-1), 1.0, atol=1e-12)
        expect = jnp.sum(_moments(dirs) * (pdf * wt)[:, None], 0)
        got = jnp.mean(_moments(wm), 0)
        se = jnp.std(_moments(wm), 0) / np.sqrt(N)
        assert np.all(np.abs(np.asarray(got - expect)) < 5 * np.asarray(se) + 2e-4), (got, expect)


def test_microfacet_direction_pdf(key):
    # Microfacet.sample returns wi with density pdf(wo, wi) over the upper hemisphere;
    # samples reflected below the horizon carry pdf 0 and are the missing mass.
    m = brdf.Microfacet(brdf.GGX(0.4), brdf.SchlickFresnel(1.0))
    wo = sph(1.2, 0.3)
    u = jax.random.uniform(key, (N, 2))
    sample = fjit(lambda m, wo, u: jax.vmap(m.sample, in_axes=(None, 0))(wo, u))
    pdf_of = fjit(lambda m, wo, wi: jax.vmap(m.pdf, in_axes=(None, 0))(wo, wi))
    wi, pdf = sample(m, wo, u)
    up = np.asarray(wi[:, 2] > 0)
    assert_close(pdf[up][:, 0], pdf_of(m, wo, wi[up])[:, 0])
    assert np.all(np.asarray(pdf[~up]) == 0)
    dirs, wt = brdf.check.hemisphere_quadrature(48, 96, breaks=(0.2, 0.6, 1.2))
    q = pdf_of(m, wo, dirs)[:, 0] * wt
    assert abs(float(jnp.sum(q)) - float(np.mean(up))) < 5 * np.sqrt(0.25 / N)
    expect = jnp.sum(_moments(dirs) * q[:, None], 0)
    got = jnp.mean(jnp.where(up[:, None], _moments(wi), 0.0), 0)
    se = jnp.std(jnp.where(up[:, None], _moments(wi), 0.0), 0) / np.sqrt(N)
    assert np.all(np.abs(np.asarray(got - expect)) < 5 * np.asarray(se) + 1e-4)

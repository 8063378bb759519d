"""Beckmann distribution and Cook-Torrance 1981: normalisation, exact Smith
masking, and the equivalence with the composable microfacet model."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.special import erf

import brdf
from tests.brdf._util import ev, fjit, sph
from tests.helpers import assert_close


@pytest.mark.parametrize("alpha", [(0.05, None), (0.5, None), (0.1, 0.4)])
def test_beckmann_projected_area_is_one(alpha):
    # integral D cos(theta_m) dwm = 1 to 1e-4 (the project's quadrature bar); the Gaussian tail is
    # light, so a few panels scaled to the roughness suffice.
    dist = brdf.Beckmann(*alpha)
    a = min(x for x in alpha if x is not None)
    dirs, w = brdf.check.hemisphere_quadrature(n_theta=64, n_phi=64, breaks=(a, 3 * a, 6 * a))
    area = float(fjit(lambda d, x, w: jnp.sum(d.D(x)[:, 0] * x[:, 2] * w))(dist, dirs, w))
    assert abs(area - 1.0) < 1e-4, area


def test_exact_lambda_and_walter_approximation():
    alpha = 0.4
    theta = np.linspace(0.05, 1.55, 200)
    w = sph(theta, 0.7)
    lam, g1 = fjit(lambda d, w: (d.Lambda(w)[:, 0], d.G1(w)[:, 0]))(brdf.Beckmann(alpha), w)
    lam, g1 = np.asarray(lam), np.asarray(g1)
    # Independent closed form (Walter et al. 2007): a = 1/(alpha tan theta).
    a = 1 / (alpha * np.tan(theta))
    ref = (erf(a) - 1) / 2 + np.exp(-(a**2)) / (2 * a * np.sqrt(np.pi))
    np.testing.assert_allclose(lam, ref, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(g1, 1 / (1 + ref), rtol=1e-12)
    # Walter's rational approximation (the one Mitsuba 3 uses) is within 0.35% of
    # the exact G1, and differs from it: this is the tolerance of the Mitsuba check.
    approx = np.where(a < 1.6, (3.535 * a + 2.181 * a**2) / (1 + 2.276 * a + 2.577 * a**2), 1.0)
    rel = np.abs(approx - g1) / g1
    assert rel.max() < 0.0035 and rel.max() > 1e-4, rel.max()


def test_cook_torrance_equals_composable_microfacet(key):
    # The paper's terms written out (CookTorrance) against the composition
    # Microfacet(Beckmann, ConductorFresnel, "v_groove"): same model, 1e-10 relative.
    wi, wo = brdf.check.random_pairs(key, 4096)
    m = jnp.asarray([0.3, 0.1, 0.6])
    eta = jnp.asarray([0.2, 1.1, 1.5])
    k = jnp.asarray([3.9, 2.4, 0.0])
    ct = brdf.CookTorrance(m, eta, k)
    mf = brdf.Microfacet(brdf.Beckmann(m), brdf.ConductorFresnel(eta, k), "v_groove")
    # Two media: a dielectric ambient (water) is the relative index.
    ct2 = brdf.CookTorrance(m, eta, k, eta_a=1.33)
    mf2 = brdf.Microfacet(brdf.Beckmann(m), brdf.ConductorFresnel(eta / 1.33, k / 1.33), "v_groove")

    @fjit
    def run(wi, wo):
        f = jax.vmap(lambda a, b: (ct(a, b), mf(a, b), ct2(a, b), mf2(a, b)))
        return f(wi, wo)

    a, b, c, d = run(wi, wo)
    assert float(jnp.max(a)) > 1.0  # the comparison covers the specular peaks
    assert_close(a, b, rtol=1e-10, atol=1e-14)
    assert_close(c, d, rtol=1e-10, atol=1e-14)


def test_cook_torrance_normal_incidence_closed_form():
    # wi = wo = n: D = 1/(pi m^2), G = 1, F = ((n-1)^2 + k^2)/((n+1)^2 + k^2).
    n = jnp.asarray([[0.0, 0.0, 1.0]])
    f = ev(brdf.CookTorrance(jnp.asarray([[0.2]]), jnp.asarray([[0.2]]), jnp.asarray([[3.9]])), n, n)
    fres = ((0.2 - 1) ** 2 + 3.9**2) / ((0.2 + 1) ** 2 + 3.9**2)
    assert_close(f, [[fres / (np.pi * 0.04) / 4]])


def test_beckmann_white_furnace():
    for alpha in (0.1, 0.6):
        m = brdf.Microfacet(brdf.Beckmann(alpha), brdf.SchlickFresnel(1.0))
        amax, _ = brdf.check.max_albedo(m, n_incident=8, n_theta=48, n_phi=32, breaks=(alpha, 3 * alpha))
        assert float(amax) <= 1.0 + 1e-6, float(amax)
        assert float(amax) > 0.7  # and it is not trivially small

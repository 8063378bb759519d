"""Composable microfacet model with GGX: normalisation, physics properties,
gradients at the edges, transformations."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdf
from tests.brdf._util import edge_directions, ev, ev_pairs, fjit, sph
from tests.helpers import REFUSED, assert_close, assert_finite

MASKINGS = ["smith", "smith_height_correlated", "v_groove"]


def projected_area(dist, alpha_min):
    """integral D(wm) cos(theta_m) dwm by composite Gauss-Legendre in theta, with
    panels scaled to the roughness so that the peak is resolved."""
    breaks = tuple(sorted({b for b in (0.3 * alpha_min, alpha_min, 3 * alpha_min, 0.8) if b < np.pi / 2 - 0.05}))
    dirs, w = brdf.check.hemisphere_quadrature(n_theta=96, n_phi=64, breaks=breaks)
    return fjit(lambda d, x, w: jnp.sum(d.D(x)[:, 0] * x[:, 2] * w))(dist, dirs, w)


@pytest.mark.parametrize("alpha", [(0.05, None), (0.3, None), (1.0, None), (0.1, 0.5), (0.7, 0.2)])
def test_ggx_projected_area_is_one(alpha):
    # Walter et al. 2007: D is normalised over projected area. Tolerance 1e-4 (the project's quadrature bar).
    # The GGX tail falls as theta'^-4 only, so the quadrature carries many panels.
    dist = brdf.GGX(*alpha)
    area = projected_area(dist, min(a for a in alpha if a is not None))
    assert abs(float(area) - 1.0) < 1e-4, float(area)


def test_ggx_isotropic_equals_anisotropic_with_equal_alphas(key):
    wi, wo = brdf.check.random_pairs(key, 256)
    a = brdf.Microfacet(brdf.GGX(0.3), brdf.SchlickFresnel(0.04))
    b = brdf.Microfacet(brdf.GGX(0.3, 0.3), brdf.SchlickFresnel(0.04))
    assert_close(ev_pairs(a, wi, wo), ev_pairs(b, wi, wo))


def test_ggx_normal_incidence_closed_form():
    # At wi = wo = n: D = 1/(pi a^2), G1 = 1, F = f0: f = f0 / (4 pi a^2).
    for alpha in (brdf.ALPHA_MIN, 0.1, 1.0):
        m = brdf.Microfacet(brdf.GGX(alpha), brdf.SchlickFresnel(0.5))
        n = jnp.asarray([[0.0, 0.0, 1.0]])
        assert_close(ev(m, n, n), [[0.5 / (4 * np.pi * alpha**2)]])


@pytest.mark.parametrize("masking", MASKINGS)
def test_nonnegative_and_reciprocal(masking, key):
    # Arrays, not Python lists: ConductorFresnel's eta and k are ArrayLike, which (as in jax.numpy) excludes lists.
    eta, k = jnp.asarray([0.2, 0.9, 1.1]), jnp.asarray([3.9, 2.4, 2.2])
    m = brdf.Microfacet(brdf.GGX(0.2, 0.6), brdf.ConductorFresnel(eta, k), masking)
    wi, wo = brdf.check.random_pairs(key, 4096)
    assert float(brdf.check.min_value(m, wi, wo)) >= 0.0
    # Reciprocal to float64 rounding (relative 1e-12 over 4096 pairs).
    assert float(brdf.check.reciprocity_error(m, wi, wo)) < 1e-12


def _ggx_albedo_normal_incidence(alpha):
    """Independent 1-D reference: at wo = n, wi = reflect(n, wm) has theta_i = 2 theta_m,
    G1(wo) = 1 and dwi = 4 cos(theta_m) dwm, so E = integral_0^{pi/4} 2 pi D cos sin G1(2 theta) dtheta."""
    from scipy.integrate import quad

    def integrand(t):
        d = alpha**2 / (np.pi * np.cos(t) ** 4 * (alpha**2 + np.tan(t) ** 2) ** 2)
        g1 = 2 / (1 + np.sqrt(1 + alpha**2 * np.tan(2 * t) ** 2))
        return 2 * np.pi * d * np.cos(t) * np.sin(t) * g1

    return quad(integrand, 0, np.pi / 4, epsabs=1e-13, epsrel=1e-12, limit=200, points=[alpha / 2])[0]


@pytest.mark.parametrize("masking", ["smith", "smith_height_correlated"])
@pytest.mark.parametrize("alpha", [0.1, 0.5, 1.0])
def test_white_furnace(masking, alpha):
    # With F = 1 the directional albedo is the single-scattering fraction: <= 1 for
    # every incident direction (Smith masking drops multiple scattering).
    m = brdf.Microfacet(brdf.GGX(alpha), brdf.SchlickFresnel(1.0), masking)
    breaks = (0.5 * alpha, 2 * alpha, min(5 * alpha, 1.4))
    amax, _ = brdf.check.max_albedo(m, n_incident=12, n_theta=48, n_phi=48, breaks=breaks)
    assert float(amax) <= 1.0 + 1e-6, float(amax)  # 1e-6: quadrature error of the lobe
    # At normal incidence both maskings reduce to G1(wi): compare with a 1-D reference.
    a0 = brdf.check.directional_albedo(m, jnp.asarray([0.0, 0.0, 1.0]), n_theta=48, n_phi=16, breaks=breaks)
    ref = _ggx_albedo_normal_incidence(alpha)
    assert abs(float(a0[0, 0]) - ref) < 1e-6, (float(a0[0, 0]), ref)  # quadrature accuracy


def test_white_furnace_mc_matches_quadrature(key):
    # Visible-normal importance sampling (Heitz 2018) and quadrature agree to 5
    # standard errors; the GGX pdf makes the estimator nearly constant.
    m = brdf.Microfacet(brdf.GGX(0.3), brdf.SchlickFresnel(1.0))
    wo = sph([0.2, 1.0, 1.45], [0.0, 0.5, 1.0])
    q = brdf.check.directional_albedo(m, wo, n_theta=48, n_phi=64, breaks=(0.1, 0.3, 0.9))
    mc, se = brdf.check.directional_albedo_mc(m, wo, key, n=1 << 15)
    assert np.all(np.abs(np.asarray(mc - q)) < 5 * np.asarray(se) + 1e-6)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_finite_values_and_gradients_at_edges(dtype):
    # Every edge pair at every roughness: 0 (clamped to the floor), the floor, 0.05,
    # 1; every masking. One program per dtype: each masking's output is checked
    # separately, and the gradient of their sum w.r.t. each model's own
    # parameters is that model's gradient.
    wi, wo = edge_directions(dtype)
    alphas = jnp.asarray([0.0, brdf.ALPHA_MIN, 0.05, 1.0], dtype)
    n = wi.shape[0]
    wi = jnp.tile(wi, (4, 1))
    wo = jnp.tile(wo, (4, 1))
    params = {
        masking: dict(alpha=jnp.repeat(alphas, n)[:, None], f0=jnp.full((4 * n, 1), 0.04, dtype),
                      rho=jnp.full((4 * n, 3), 0.5, dtype))
        for masking in MASKINGS
    }

    def f(params, a, b):
        out = {}
        for masking, p in params.items():
            m = brdf.Sum(
                brdf.Lambert(p["rho"]), brdf.Microfacet(brdf.GGX(p["alpha"]), brdf.SchlickFresnel(p["f0"]), masking)
            )
            out[masking] = m(a, b)
        return out

    def total(p, a, b):
        return sum(jnp.sum(v) for v in f(p, a, b).values())

    vals, g = fjit(lambda p, a, b: (f(p, a, b), jax.grad(total, argnums=(0, 1, 2))(p, a, b)))(params, wi, wo)
    below = (wi[:, 2] <= 0) | (wo[:, 2] <= 0)
    for masking, v in vals.items():
        assert v.dtype == dtype and v.shape == (4 * n, 3)
        assert_finite(v)
        assert float(jnp.min(v)) >= 0, masking
        assert_close(v[below], 0.0)
    assert_finite(g)


def test_jit_vmap_eager_agree(key):
    p = 64
    k1, k2, k3 = jax.random.split(key, 3)
    wi, wo = brdf.check.random_pairs(k1, p)
    rho = jax.random.uniform(k2, (p, 3))
    alpha = jax.random.uniform(k3, (p, 1), minval=0.05, maxval=1.0)
    m = brdf.lambert_ggx(rho, jnp.full((p, 1), 0.04), alpha)
    eager = m(wi, wo)
    jitted = jax.jit(lambda m, a, b: m(a, b))(m, wi, wo)
    mapped = fjit(jax.vmap(lambda m, a, b: m(a, b)))(m, wi, wo)  # texture and directions mapped together
    assert_close(jitted, eager)
    assert_close(mapped, eager)
    # Directions [P, 3] against 0-d parameters broadcast to the same answer.
    one = brdf.lambert_ggx(0.3, 0.04, 0.5)
    assert_close(ev(one, wi, wo), ev_pairs(one, wi, wo))


def test_float32_matches_float64(key):
    wi, wo = brdf.check.random_pairs(key, 512)
    m64 = brdf.Microfacet(brdf.GGX(0.2), brdf.SchlickFresnel(0.04))
    m32 = brdf.Microfacet(brdf.GGX(jnp.float32(0.2)), brdf.SchlickFresnel(jnp.float32(0.04)))
    f64 = ev(m64, wi, wo)
    f32 = ev(m32, wi.astype(jnp.float32), wo.astype(jnp.float32))
    assert f32.dtype == jnp.float32
    assert_close(f32, f64, jnp.float32, rtol=2e-5)  # float32 rounding through ~30 operations


def test_invalid_inputs_raise():
    with pytest.raises(ValueError, match="alpha_x"):
        brdf.GGX(-0.1)
    with pytest.raises(ValueError, match="alpha_y"):
        brdf.GGX(0.1, jnp.asarray([0.2, -1.0]))
    with pytest.raises(ValueError, match="f0"):
        brdf.SchlickFresnel(1.5)
    with pytest.raises(ValueError, match="masking"):
        brdf.Microfacet(brdf.GGX(0.1), brdf.SchlickFresnel(0.04), "smith_uncorrelated")
    # Swapped arguments also break Microfacet's annotation: the test-time checker refuses them first.
    with pytest.raises(REFUSED, match="distribution"):
        brdf.Microfacet(brdf.SchlickFresnel(0.04), brdf.GGX(0.1))
    m = brdf.Microfacet(brdf.GGX(jnp.full((4, 1), 0.1)), brdf.SchlickFresnel(0.04))
    with pytest.raises(ValueError, match="alpha_x"):
        m(jnp.zeros((2, 4, 3)), jnp.zeros((2, 4, 3)))


def test_construction_under_jit_does_not_inspect_tracers():
    # Validation happens only on concrete values; traced construction works.
    @fjit
    def f(alpha):
        return brdf.Microfacet(brdf.GGX(alpha), brdf.SchlickFresnel(0.04))(
            jnp.asarray([[0.0, 0.0, 1.0]]), jnp.asarray([[0.0, 0.0, 1.0]])
        )

    assert_close(f(jnp.asarray([[0.5]])), [[0.04 / (4 * np.pi * 0.25)]])

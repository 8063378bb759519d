"""The free physics kernels (microfacet D, Lambda, G1; Smith G2 forms; Schlick and
the dielectric transmittance; the Blinn-Phong lobe and the Phong-exponent
correspondence) and the shared patterns (Fibonacci points, orthonormal frames):
each against the Module method it replaced or a closed form, component-major ==
last-axis layout, float64 finite differences, finite gradients at the edges in
float32, jit == vmap == eager."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

import brdf
from tests.brdf._util import edge_directions, fjit, from_cos
from tests.helpers import assert_close, assert_finite

FAMILIES = ("ggx", "beckmann")
# kernel name -> Module method it replaced
TERMS = {"d": "D", "lambda": "Lambda", "lambda_cos": "lambda_cos", "g1": "G1", "g1_over_cos": "g1_over_cos"}
MODULES = {"ggx": brdf.GGX, "beckmann": brdf.Beckmann}
ALPHAS = [(brdf.ALPHA_MIN, None), (0.05, None), (0.3, None), (1.0, None), (0.1, 0.5), (0.7, 0.2)]


def kernel(family, term):
    return getattr(brdf, f"{family}_{term}")


def kernel_xyz(family, term):
    return getattr(brdf, f"{family}_{term}_xyz")


def random_dirs(key, n, dtype=jnp.float64, lower=False):
    """n unit directions [n, 3], upper hemisphere (or the whole sphere with ``lower``)."""
    d = jax.random.normal(key, (n, 3), dtype)
    d = d / jnp.linalg.norm(d, axis=-1, keepdims=True)
    return d if lower else d.at[:, 2].set(jnp.abs(d[:, 2]))


# --- microfacet distributions -------------------------------------------------------------


@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("term", TERMS)
@pytest.mark.parametrize("alpha", ALPHAS)
def test_kernel_equals_module_method(family, term, alpha, key):
    # The Module now calls the kernel: identical to the last bit, on both hemispheres.
    w = random_dirs(key, 64, lower=True)
    got = kernel(family, term)(w, *alpha)
    want = getattr(MODULES[family](*alpha), TERMS[term])(w)
    np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("term", TERMS)
def test_component_major_equals_last_axis(family, term, key):
    # The fitter's layout: rows x, y, z of [3, N] and per-sample alphas [N];
    # the Modules': [N, 3] and [N, 1]. One formula, so equal to 1e-12 (float64).
    k1, k2 = jax.random.split(key)
    w = random_dirs(k1, 128, lower=True)
    a = jax.random.uniform(k2, (2, 128), jnp.float64, 1e-3, 1.0)
    cm = kernel_xyz(family, term)(*w.T, a[0], a[1])
    la = kernel(family, term)(w, a[0][:, None], a[1][:, None])
    assert cm.shape == (128,) and la.shape == (128, 1)
    assert_close(cm, la[:, 0], rtol=0, atol=1e-12)


def roughness_breaks(alpha):
    """Quadrature panel edges in theta scaled to the smallest roughness of ``alpha``."""
    amin = min(a for a in alpha if a is not None)
    return tuple(sorted({b for b in (0.3 * amin, amin, 3 * amin, 0.8) if b < np.pi / 2 - 0.05}))


def projected_area(d_fn, alpha):
    """integral D(wm) cos(theta_m) dwm by composite Gauss-Legendre (panels scaled to the roughness)."""
    dirs, w = brdf.check.hemisphere_quadrature(n_theta=96, n_phi=64, breaks=roughness_breaks(alpha))
    return jnp.sum(d_fn(dirs, *alpha)[:, 0] * dirs[:, 2] * w)


@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("alpha", [(0.05, None), (0.3, None), (1.0, None), (0.1, 0.5)])
def test_d_is_normalised_over_projected_area(family, alpha):
    # Walter et al. 2007, eq. 4: integral D cos = 1. Tolerance 1e-4: the quadrature
    # error of GGX's theta^-4 tail with 96 nodes per panel (as in test_microfacet).
    area = projected_area(kernel(family, "d"), alpha)
    assert abs(float(area) - 1.0) < 1e-4, float(area)


@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("alpha", [(0.05, None), (0.3, None), (1.0, None), (0.1, 0.5)])
def test_visible_normals_are_normalised(family, alpha):
    # Heitz 2014, eq. 18 / Heitz 2018 sec. 2: integral G1(wo) max(0, wo.wm) D(wm) dwm = cos(theta_o),
    # i.e. G1/cos(wo) times that integral is 1: D and Lambda are consistent. 1e-5: the
    # quadrature error at the kink wo.wm = 0 (measured <= 3e-7 with these nodes).
    dirs, w = brdf.check.hemisphere_quadrature(n_theta=96, n_phi=256, breaks=roughness_breaks(alpha))
    d = kernel(family, "d")(dirs, *alpha)[:, 0]
    for cz in (1.0, 0.5, 0.05):
        wo = from_cos(cz, 0.4)
        g = kernel(family, "g1_over_cos")(wo[None], *alpha)[0, 0]
        total = g * jnp.sum(jnp.maximum(dirs @ wo, 0.0) * d * w)
        assert abs(float(total) - 1.0) < 1e-5, (cz, float(total))


@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("alpha", ALPHAS)
def test_smith_identities(family, alpha, key):
    # G1 = 1 / (1 + Lambda), G1/cos * cos = G1, cos * Lambda = lambda_cos, above the horizon.
    w = random_dirs(key, 256)
    w = w.at[:, 2].set(jnp.maximum(w[:, 2], 1e-3))
    lam = kernel(family, "lambda")(w, *alpha)
    g1 = kernel(family, "g1")(w, *alpha)
    z = w[:, 2:3]
    assert_close(g1, 1.0 / (1.0 + lam))
    assert_close(kernel(family, "g1_over_cos")(w, *alpha) * z, g1)
    assert_close(kernel(family, "lambda_cos")(w, *alpha), z * lam, rtol=1e-10, atol=1e-14)
    # Below the horizon G1, G1/cos and cos*Lambda are 0; Lambda depends on |z|.
    below = w * jnp.asarray([[1.0, 1.0, -1.0]])
    for term in ("g1", "g1_over_cos", "lambda_cos"):
        assert float(jnp.max(jnp.abs(kernel(family, term)(below, *alpha)))) == 0.0
    assert_close(kernel(family, "lambda")(below, *alpha), lam)


def test_ggx_closed_forms():
    # Isotropic GGX: Lambda = (sqrt(1 + a^2 tan^2) - 1) / 2, G1 = 2 / (1 + sqrt(1 + a^2 tan^2))
    # (Walter et al. 2007, eq. 34), D(n) = 1 / (pi a^2) (eq. 33).
    theta = np.linspace(0.05, 1.5, 30)
    for a in (brdf.ALPHA_MIN, 0.2, 0.9):
        w = from_cos(np.cos(theta), 0.7)
        root = np.sqrt(1 + a * a * np.tan(theta) ** 2)
        assert_close(brdf.ggx_lambda(w, a)[:, 0], (root - 1) / 2, rtol=1e-9, atol=1e-15)
        assert_close(brdf.ggx_g1(w, a)[:, 0], 2 / (1 + root))
        n = jnp.asarray([[0.0, 0.0, 1.0]])
        assert_close(brdf.ggx_d(n, a), [[1 / (np.pi * a * a)]])
        assert_close(brdf.ggx_g1(n, a), [[1.0]])


def test_beckmann_closed_forms():
    # Exact Smith Lambda (Walter et al. 2007, sec. 5.1): (erf(b) - 1)/2 + exp(-b^2)/(2 b sqrt(pi)),
    # b = 1 / (a tan(theta)); D(n) = 1 / (pi ax ay).
    from scipy.special import erf

    theta = np.linspace(0.05, 1.5, 30)
    for a in (0.05, 0.3, 1.0):
        w = from_cos(np.cos(theta), 2.1)
        b = 1 / (a * np.tan(theta))
        ref = (erf(b) - 1) / 2 + np.exp(-b * b) / (2 * b * np.sqrt(np.pi))
        # absolute 1e-15: ref itself cancels (erf(b) - 1 ~ -1e-16) when b is large
        assert_close(brdf.beckmann_lambda(w, a)[:, 0], ref, rtol=1e-9, atol=1e-15)
    n = jnp.asarray([[0.0, 0.0, 1.0]])
    assert_close(brdf.beckmann_d(n, 0.2, 0.5), [[1 / (np.pi * 0.1)]])
    assert_close(brdf.beckmann_g1(n, 0.2, 0.5), [[1.0]])


def test_alpha_floor_and_isotropic_default():
    w = from_cos(np.array([0.3, 0.9]), np.array([0.1, 2.0]))
    for family in FAMILIES:
        for term in TERMS:
            f = kernel(family, term)
            # below the floor ALPHA_MIN evaluates as the floor; alpha_y None is alpha_y = alpha_x
            assert_close(f(w, 0.0), f(w, brdf.ALPHA_MIN, brdf.ALPHA_MIN))
            assert_close(f(w, 0.4), f(w, 0.4, 0.4))


# --- Smith G2 forms, Fresnel, Blinn-Phong -------------------------------------------------


def composed_lobe_cm(wi, wo, ax, ay, f0):
    """The fitter's GGX/Schlick/separable-Smith lobe, component-major (rows of [3, N])."""
    hx, hy, hz = wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]
    sq = hx * hx + hy * hy + hz * hz
    ok = sq > 1e-30
    inv = jnp.where(ok, 1 / jnp.sqrt(jnp.where(ok, sq, 1.0)), 0.0)
    mx, my, mz = hx * inv, hy * inv, hz * inv
    cos_d = wi[0] * mx + wi[1] * my + wi[2] * mz
    g = brdf.smith_g2_separable_over_cos(brdf.ggx_g1_over_cos_xyz(*wi, ax, ay), brdf.ggx_g1_over_cos_xyz(*wo, ax, ay))
    f = brdf.ggx_d_xyz(mx, my, mz, ax, ay) * brdf.schlick(cos_d, f0) * g
    return jnp.where((wi[2] > 0) & (wo[2] > 0), f, 0.0)


@pytest.mark.parametrize("masking", ["smith", "smith_height_correlated", "v_groove"])
@pytest.mark.parametrize("family", FAMILIES)
def test_g2_kernels_compose_to_microfacet(masking, family, key):
    # The kernels composed by hand equal brdf.Microfacet (last-axis Module) to 1e-12.
    k1, k2 = jax.random.split(key)
    wi, wo = random_dirs(k1, 128), random_dirs(k2, 128)
    ax, ay = 0.25, 0.6
    wm = brdf.safe_normalize(wi + wo)
    zi, zo = wi[:, 2:3], wo[:, 2:3]
    if masking == "smith":
        g = brdf.smith_g2_separable_over_cos(kernel(family, "g1_over_cos")(wi, ax, ay),
                                             kernel(family, "g1_over_cos")(wo, ax, ay))
    elif masking == "smith_height_correlated":
        g = brdf.smith_g2_height_correlated_over_cos(zi, zo, kernel(family, "lambda_cos")(wi, ax, ay),
                                                     kernel(family, "lambda_cos")(wo, ax, ay))
    else:
        g = brdf.v_groove_g2_over_cos(zi, zo, wm[:, 2:3], brdf.dot(wo, wm))
    f = kernel(family, "d")(wm, ax, ay) * brdf.schlick(brdf.dot(wi, wm), 0.04) * g
    m = brdf.Microfacet(MODULES[family](ax, ay), brdf.SchlickFresnel(0.04), masking)
    assert_close(f, m(wi, wo), rtol=1e-12, atol=0)


def test_component_major_lobe_equals_microfacet(key):
    # What relight's fitter evaluates, in its [3, N] layout, against the Module in [N, 3].
    k1, k2 = jax.random.split(key)
    wi, wo = random_dirs(k1, 256, lower=True), random_dirs(k2, 256, lower=True)
    got = composed_lobe_cm(wi.T, wo.T, 0.2, 0.45, 0.3)
    want = brdf.Microfacet(brdf.GGX(0.2, 0.45), brdf.SchlickFresnel(0.3), "smith")(wi, wo)[:, 0]
    assert_close(got, want, rtol=0, atol=1e-12)


def test_g2_closed_forms():
    # Separable: G1 G1 / (4 ci co); height-correlated at normal incidence: 1/4; V-groove
    # unshadowed at wi = wo = n: 1/4.
    assert_close(brdf.smith_g2_separable_over_cos(2.0, 3.0), 1.5)
    assert_close(brdf.smith_g2_height_correlated_over_cos(1.0, 1.0, 0.0, 0.0), 0.25)
    assert_close(brdf.smith_g2_height_correlated_over_cos(0.0, 0.0, 0.0, 0.0), 0.0)  # guarded 1/0
    assert_close(brdf.v_groove_g2_over_cos(1.0, 1.0, 1.0, 1.0), 0.25)
    # shadowed: zm = 1, zi = zo = 0.2, wo.wm = 0.8: G = 2 * 0.2 / 0.8 = 0.5, / (4 * 0.04)
    assert_close(brdf.v_groove_g2_over_cos(0.2, 0.2, 1.0, 0.8), 0.5 / 0.16)


def test_schlick_closed_forms():
    f0 = jnp.asarray([[0.02, 0.04, 0.9]])
    assert_close(brdf.schlick(jnp.ones((1, 1)), f0), f0)
    assert_close(brdf.schlick(jnp.zeros((1, 1)), f0), jnp.ones((1, 3)))
    assert_close(brdf.schlick(jnp.full((1, 1), 0.5), f0), f0 + (1 - f0) / 32)
    # cos is clamped to [0, 1]
    assert_close(brdf.schlick(jnp.asarray([-0.3, 1.7]), 0.04), [1.0, 0.04])
    assert_close(brdf.SchlickFresnel(f0)(jnp.full((1, 1), 0.3)), brdf.schlick(jnp.full((1, 1), 0.3), f0))


def test_fresnel_transmittance_closed_forms():
    for eta in (1.0, 1.33, 1.4, 2.5):
        r0 = ((eta - 1) / (eta + 1)) ** 2
        assert_close(brdf.fresnel_transmittance(1.0, eta), 1 - r0)
        assert_close(brdf.fresnel_transmittance(1.0, 1 / eta), 1 - r0)  # same from either side
    c = jnp.linspace(-0.5, 1.5, 41)
    assert_close(brdf.fresnel_transmittance(c, 1.4), 1 - brdf.fresnel_dielectric(jnp.clip(c, 0, 1), 1.4))
    assert_close(brdf.fresnel_transmittance(0.0, 1.4), 0.0)  # grazing: all reflected
    assert_close(brdf.fresnel_transmittance(0.3, 1 / 1.4), 0.0)  # total internal reflection (sin > 1/1.4)
    t = brdf.fresnel_transmittance(c, 1.4)
    assert float(jnp.min(t)) >= 0.0 and float(jnp.max(t)) <= 1.0


def blinn_phong_albedo_normal_incidence(s):
    """Closed form of integral (s + 8)/(8 pi) cos^s(theta_h) cos(theta_i) dwi at wo = n,
    where theta_h = theta_i / 2: (s + 8) [2 v^(s+4)/(s+4) - v^(s+2)/(s+2)] from v = 1/sqrt2 to 1."""
    f = lambda v: 2 * v ** (s + 4) / (s + 4) - v ** (s + 2) / (s + 2)  # noqa: E731
    return (s + 8) * (f(1.0) - f(2**-0.5))


@pytest.mark.parametrize("s", [0.0, 1.0, 10.0, 100.0, 1000.0])
def test_blinn_phong_lobe_energy_closed_form(s):
    # At normal incidence wo = n; the lobe's albedo (rho_s = 1) by quadrature against
    # the closed form, 1e-8 relative (Gauss-Legendre panels scaled to the lobe's width).
    width = min(2.0 / np.sqrt(s + 1.0), 1.0)  # theta_i where cos^s(theta_i / 2) has fallen by e^-0.5
    dirs, w = brdf.check.hemisphere_quadrature(n_theta=64, n_phi=8, breaks=(0.5 * width, width, 3 * width))
    n = jnp.asarray([0.0, 0.0, 1.0])
    cos_h = brdf.safe_normalize(dirs + n[None])[:, 2]
    albedo = jnp.sum(brdf.blinn_phong_lobe(cos_h, 1.0, s) * dirs[:, 2] * w)
    assert_close(albedo, blinn_phong_albedo_normal_incidence(s), rtol=1e-8)
    if s == 10.0:
        assert 1.07 < float(albedo) < 1.08  # docs/brdf.md: "1.07 at n = 10"


def test_blinn_phong_lobe_forms_and_module(key):
    c = jnp.asarray([-0.2, 0.0, 0.3, 1.0])
    assert_close(brdf.blinn_phong_lobe(c, 0.5, 4.0), 0.5 * 12 / (8 * np.pi) * jnp.maximum(c, 0) ** 4)
    assert_close(brdf.blinn_phong_lobe(c, 0.5, 4.0, normalized=False), 0.5 * jnp.maximum(c, 0) ** 4)
    # BlinnPhong = rho_d / pi + the lobe at cos_h = n.normalize(wi + wo)
    wi, wo = brdf.check.random_pairs(key, 64)
    m = brdf.BlinnPhong(0.2, 0.5, 30.0)
    cos_h = brdf.safe_normalize(wi + wo)[:, 2:3]
    assert_close(m(wi, wo), 0.2 / np.pi + brdf.blinn_phong_lobe(cos_h, 0.5, 30.0))


def test_phong_exponent_round_trip():
    alpha = jnp.geomspace(brdf.ALPHA_MIN, 1.0, 50)
    s = brdf.phong_exponent(alpha)
    # Walter et al. 2007, sec. 5.2: s = 2 / alpha^2 - 2 (relight's former formula), 0 at alpha = 1
    assert_close(s, jnp.maximum(2 / alpha**2 - 2, 0.0))
    assert_close(brdf.alpha_from_phong_exponent(s), alpha)
    e = jnp.asarray([0.0, 1.0, 30.0, 1e4])
    assert_close(brdf.phong_exponent(brdf.alpha_from_phong_exponent(e)), e, rtol=1e-9)
    assert_close(brdf.phong_exponent(jnp.asarray([1.0, 2.0])), [0.0, 0.0])
    # below the floor the exponent is the floor's (finite; the lobe stays finite in float32)
    assert_close(brdf.phong_exponent(0.0), 2 / brdf.ALPHA_MIN**2 - 2)


# --- gradients, edges, transformations ---------------------------------------------------


def _fd(f, args):
    # Central differences in float64 against forward and reverse mode (kornia's gradcheck,
    # optimistix's JVP tests). eps = 1e-6: truncation ~ eps^2 f''' and rounding ~ 1e-16/eps,
    # so 1e-6 relative holds for these smooth, O(1) functions.
    check_grads(f, args, order=1, modes=("fwd", "rev"), eps=1e-6, atol=1e-6, rtol=1e-6)


@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("term", TERMS)
def test_finite_difference_gradients_distributions(family, term):
    # Interior points (z in [0.2, 0.95], alpha in [0.2, 0.8]), away from the masks.
    theta = np.array([0.3, 0.8, 1.2, 1.35])
    w = from_cos(np.cos(theta), np.array([0.1, 1.3, 2.9, 4.4]))
    ax = jnp.asarray([0.2, 0.5, 0.8, 0.35])
    ay = jnp.asarray([0.6, 0.3, 0.8, 0.25])
    _fd(kernel_xyz(family, term), (*w.T, ax, ay))


def test_finite_difference_gradients_elementwise():
    c = jnp.asarray([0.15, 0.5, 0.85])
    _fd(brdf.schlick, (c, jnp.asarray([0.04, 0.3, 0.9])))
    _fd(brdf.fresnel_transmittance, (c, jnp.asarray([1.33, 1.4, 2.0])))
    _fd(brdf.blinn_phong_lobe, (c, jnp.asarray([0.3, 0.5, 1.0]), jnp.asarray([0.5, 4.0, 20.0])))
    _fd(brdf.phong_exponent, (jnp.asarray([0.1, 0.4, 0.9]),))
    _fd(brdf.alpha_from_phong_exponent, (jnp.asarray([0.5, 10.0, 300.0]),))
    _fd(brdf.smith_g2_separable_over_cos, (jnp.asarray([1.2, 2.0]), jnp.asarray([3.0, 1.1])))
    _fd(brdf.smith_g2_height_correlated_over_cos,
        (jnp.asarray([0.3, 0.9]), jnp.asarray([0.6, 0.2]), jnp.asarray([0.05, 0.4]), jnp.asarray([0.2, 0.01])))
    # V-groove: one point on each branch (shadowed: 2 zm lo < wo.wm), away from the switch
    _fd(brdf.v_groove_g2_over_cos,
        (jnp.asarray([0.9, 0.2]), jnp.asarray([0.8, 0.3]), jnp.asarray([0.95, 0.9]), jnp.asarray([0.9, 0.8])))


def _edge_components(dtype):
    """Directions at the edges (grazing 1e-7 and 0 on both sides, normal incidence,
    below the horizon) as rows x, y, z, each paired with every roughness edge."""
    wi, _ = edge_directions(dtype)
    wi = jnp.concatenate([wi, jnp.asarray([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]], dtype)])
    alphas = jnp.asarray([[brdf.ALPHA_MIN, brdf.ALPHA_MIN], [0.0, 0.0], [brdf.ALPHA_MIN, 1.0], [0.3, 0.3], [1.0, 1.0]],
                         dtype)
    w = jnp.repeat(wi, alphas.shape[0], axis=0)
    a = jnp.tile(alphas, (wi.shape[0], 1))
    return w[:, 0], w[:, 1], w[:, 2], a[:, 0], a[:, 1]


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_finite_values_and_gradients_at_edges(dtype):
    args = _edge_components(dtype)

    def all_kernels(x, y, z, ax, ay):
        return [kernel_xyz(f, t)(x, y, z, ax, ay) for f in FAMILIES for t in TERMS]

    def total(*a):
        # Lambda is the dtype's max at the horizon: weight it down so that the sum is finite.
        return sum(jnp.sum(v * 1e-30) if i % 5 == 1 else jnp.sum(v) for i, v in enumerate(all_kernels(*a)))

    vals, grads = fjit(lambda *a: (all_kernels(*a), jax.grad(total, argnums=tuple(range(5)))(*a)))(*args)
    assert_finite(vals, grads)
    assert all(v.dtype == dtype for v in vals)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_finite_gradients_of_the_composed_lobe_at_edges(dtype):
    # Edge pairs: grazing, wi = wo, mirror pairs, normal incidence; alpha at and below the floor.
    wi, wo = edge_directions(dtype)
    for alpha in (brdf.ALPHA_MIN, 0.0, 0.5):
        a = jnp.asarray(alpha, dtype)
        f0 = jnp.asarray(0.04, dtype)
        f = fjit(lambda wi, wo, a, f0: (composed_lobe_cm(wi.T, wo.T, a, a, f0),
                                        jax.grad(lambda *p: jnp.sum(composed_lobe_cm(p[0].T, p[1].T, p[2], p[2], p[3])),
                                                 argnums=(0, 1, 2, 3))(wi, wo, a, f0)))
        vals, grads = f(wi, wo, a, f0)
        assert_finite(vals, grads)
        assert vals.dtype == dtype


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_elementwise_kernels_finite_at_edges(dtype):
    c = jnp.asarray([-1.0, -1e-7, 0.0, 1e-7, 0.5, 1.0 - 1e-7, 1.0, 1.5], dtype)
    one = jnp.ones_like(c)
    s = jnp.asarray([0.0, 1.0, 2e8, 0.0, 30.0, 2e8, 2e8, 1.0], dtype)
    fns = {
        "schlick": lambda c, s, p: brdf.schlick(c, 0.04 * p),
        "transmittance": lambda c, s, p: brdf.fresnel_transmittance(c, 1.4 * p),
        "transmittance_tir": lambda c, s, p: brdf.fresnel_transmittance(c, p / 1.4),
        "lobe": lambda c, s, p: brdf.blinn_phong_lobe(c, 0.5 * p, s * p),
        "lobe_unnormalized": lambda c, s, p: brdf.blinn_phong_lobe(c, 0.5 * p, s * p, normalized=False),
        "phong_exponent": lambda c, s, p: brdf.phong_exponent(jnp.abs(c) * p),  # alpha 0, 1e-7, ..., 1.5
        "alpha_from": lambda c, s, p: brdf.alpha_from_phong_exponent((c - 1) * 2 * p),  # exponent -4 .. 1, -2 included
        "g2_hc": lambda c, s, p: brdf.smith_g2_height_correlated_over_cos(jnp.abs(c), jnp.abs(c) * p, 0 * c, 0 * c),
        "v_groove": lambda c, s, p: brdf.v_groove_g2_over_cos(jnp.abs(c), p, p, p),
    }
    # one program for all of them (the values and gradients do not depend on how they are compiled)
    out = fjit(lambda c, s, one: {name: jax.vmap(jax.value_and_grad(f, argnums=(0, 1, 2)))(c, s, one)
                                  for name, f in fns.items()})(c, s, one)
    for name, (v, g) in out.items():
        assert_finite(v, g)
        assert v.dtype == dtype, name


@pytest.mark.parametrize("family", FAMILIES)
def test_jit_vmap_eager_agree(family, key):
    k1, k2 = jax.random.split(key)
    w = random_dirs(k1, 32, lower=True)
    a = jax.random.uniform(k2, (2, 32), jnp.float64, 1e-3, 1.0)
    # eager (op by op) against one jitted program holding every kernel (XLA's default options), and one vmapped
    xyz = [kernel_xyz(family, term) for term in TERMS]
    last = [kernel(family, term) for term in TERMS]
    c = w[:, 2]
    elementwise = ((brdf.schlick, (c, a[0])), (brdf.fresnel_transmittance, (c, 1 + a[0])),
                   (brdf.blinn_phong_lobe, (c, a[0], 100 * a[1])), (brdf.phong_exponent, (a[0],)),
                   (brdf.alpha_from_phong_exponent, (100 * a[0],)))

    def every(w, a0, a1, el_args, mapped):
        run = jax.vmap if mapped else (lambda f: f)
        return ([run(f)(*w.T, a0, a1) for f in xyz], [g(w, a0[:, None], a1[:, None]) for g in last],
                [run(f)(*args) for (f, _), args in zip(elementwise, el_args, strict=True)])

    el_args = [args for _, args in elementwise]
    jitted = jax.jit(every, static_argnums=4)(w, a[0], a[1], el_args, False)
    mapped = fjit(every, static_argnums=4)(w, a[0], a[1], el_args, True)
    for f, j, m in zip(xyz, jitted[0], mapped[0], strict=True):
        eager = f(*w.T, a[0], a[1])
        assert_close(j, eager)
        assert_close(m, eager)
    for g, j in zip(last, jitted[1], strict=True):
        assert_close(j, g(w, a[0][:, None], a[1][:, None]))
    for (f, args), j, m in zip(elementwise, jitted[2], mapped[2], strict=True):
        assert_close(j, f(*args))
        assert_close(m, f(*args))


# --- Fibonacci points -----------------------------------------------------------------------


def stage_fibonacci_reference(n, hemisphere=False):
    """stage.fibonacci_sphere's directions as it computed them before it moved to brdf (frozen)."""
    k = np.arange(n, dtype=np.float64)
    golden = (1 + 5**0.5) / 2
    y = 1 - (2 * k + 1) / n
    if hemisphere:
        y = 1 - (k + 0.5) / n
    r = np.sqrt(np.maximum(1 - y * y, 0))
    phi = 2 * np.pi * k / golden
    return np.stack([r * np.cos(phi), y, r * np.sin(phi)], axis=1)


@pytest.mark.parametrize("hemisphere", [False, True])
def test_fibonacci_reproduces_stage_exactly(hemisphere):
    import stage

    for n in (4, 7, 200, 1001):
        d = brdf.fibonacci_sphere(n, axis=1, hemisphere=hemisphere)
        assert d.dtype == np.float64 and d.shape == (n, 3)
        np.testing.assert_array_equal(d, stage_fibonacci_reference(n, hemisphere))
        rig = stage.fibonacci_sphere(n, hemisphere=hemisphere)
        # the rig stores float32 positions at the default radius_mm = 1000: exactly those of d
        np.testing.assert_array_equal(np.asarray(rig.position), (d * 1000.0).astype(np.float32))


def test_fibonacci_axes_and_hemisphere():
    d1 = brdf.fibonacci_sphere(50, axis=1)
    # pole along axis a, the other two components in increasing index order
    np.testing.assert_array_equal(brdf.fibonacci_sphere(50, axis=2), d1[:, [0, 2, 1]])
    np.testing.assert_array_equal(brdf.fibonacci_sphere(50, axis=0), d1[:, [1, 0, 2]])
    np.testing.assert_array_equal(brdf.fibonacci_sphere(50), brdf.fibonacci_sphere(50, axis=2))
    h = brdf.fibonacci_hemisphere(64)
    np.testing.assert_array_equal(h, brdf.fibonacci_sphere(64, axis=2, hemisphere=True))
    assert np.all(h[:, 2] > 0)
    for bad in (0, -3):
        with pytest.raises(ValueError, match="n >= 1"):
            brdf.fibonacci_sphere(bad)
    with pytest.raises(ValueError, match="axis"):
        brdf.fibonacci_sphere(10, axis=3)


@pytest.mark.parametrize("n", [50, 200, 1000])
def test_fibonacci_is_nearly_uniform(n):
    d = brdf.fibonacci_sphere(n)
    assert_close(np.linalg.norm(d, axis=1), np.ones(n))
    # Equal-area bands: exactly k of the n points lie above the band edge 1 - 2k/n.
    for k in (1, n // 4, n // 2):
        assert np.sum(d[:, 2] > 1 - 2 * k / n) == k
    # The mean direction is ~0 (no bias): |mean| < 1 / n.
    assert np.linalg.norm(d.mean(0)) < 1.0 / n
    # Nearest-neighbour spacing ~ sqrt(4 pi / n), the side of each point's share of the
    # sphere: the mean within 10% (measured 0.93-0.97 for n = 50-4000) and no two
    # points closer than 0.8 of it (measured 0.87: no clumping).
    dist = np.linalg.norm(d[:, None] - d[None], axis=-1)
    np.fill_diagonal(dist, np.inf)
    nn = dist.min(axis=1) / np.sqrt(4 * np.pi / n)
    assert abs(nn.mean() - 1) < 0.1, nn.mean()
    assert nn.min() > 0.8, nn.min()
    h = brdf.fibonacci_hemisphere(n)
    dist = np.linalg.norm(h[:, None] - h[None], axis=-1)
    np.fill_diagonal(dist, np.inf)
    assert abs((dist.min(axis=1) / np.sqrt(2 * np.pi / n)).mean() - 1) < 0.1


# --- orthonormal frames ----------------------------------------------------------------------


def _check_frame(t, b, n, atol):
    eye = np.eye(3)
    for v in (t, b):
        assert_close(np.linalg.norm(v, axis=-1), np.ones(v.shape[0]), rtol=0, atol=atol)
    assert_close(np.sum(t * b, -1), 0 * t[:, 0], rtol=0, atol=atol)
    assert_close(np.sum(t * n, -1), 0 * t[:, 0], rtol=0, atol=atol)
    assert_close(np.sum(b * n, -1), 0 * t[:, 0], rtol=0, atol=atol)
    assert_close(np.cross(t, b), n, rtol=0, atol=atol)  # right-handed: t x b = n
    m = np.stack([t, b, n], axis=-2)
    assert_close(m @ np.swapaxes(m, -1, -2), np.broadcast_to(eye, m.shape), rtol=0, atol=atol)


def _hard_normals(dtype):
    eps = 1e-7 if dtype == jnp.float64 else 1e-3
    n = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.6, 0.8, 0.0],
                  [0.6, 0.8, -0.0], [eps, 0.0, -1.0], [0.0, -eps, -1.0], [eps, eps, -1.0], [eps, 0.0, 1.0],
                  [0.3, 0.4, -eps], [0.3, 0.4, eps]])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_orthonormal_basis(dtype, key):
    n = np.concatenate([_hard_normals(dtype), np.asarray(random_dirs(key, 256, lower=True))])
    t, b = brdf.orthonormal_basis(jnp.asarray(n, dtype))
    assert t.dtype == dtype and t.shape == n.shape
    atol = 1e-12 if dtype == jnp.float64 else 2e-6  # 2e-6: a few float32 ulps of 1
    _check_frame(np.asarray(t, np.float64), np.asarray(b, np.float64), n.astype(dtype).astype(np.float64), atol)
    # n = -z exactly: t = x, b = -y (Duff et al. 2017's sign branch, no division by ~0)
    t0, b0 = brdf.orthonormal_basis(jnp.asarray([0.0, 0.0, -1.0], dtype))
    assert_close(t0, [1.0, 0.0, 0.0])
    assert_close(b0, [0.0, -1.0, 0.0])
    # finite gradients at and near the south pole
    g = jax.grad(lambda v: sum(jnp.sum(u * jnp.arange(1.0, 4.0, dtype=dtype)) for u in brdf.orthonormal_basis(v)))
    assert_finite(fjit(jax.vmap(g))(jnp.asarray(_hard_normals(dtype), dtype)))


def stage_frame_reference(n, t_guess):
    """stage._surface._orthonormal_frame as it was before it moved to brdf (frozen)."""
    t = t_guess - n * np.sum(n * t_guess, axis=1, keepdims=True)
    bad = np.linalg.norm(t, axis=1) < 1e-8
    if np.any(bad):
        alt = np.where(np.abs(n[bad, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
        t[bad] = alt - n[bad] * np.sum(n[bad] * alt, axis=1, keepdims=True)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    b = np.cross(n, t)
    return t, b


def _frame_inputs():
    rng = np.random.default_rng(7)
    n = rng.normal(size=(200, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    tg = rng.normal(size=(200, 3))
    tg[:20] = 0.0  # no tangent at all
    tg[20:40] = 3.0 * n[20:40]  # tangent parallel to the normal
    tg[40:45] = n[40:45] + 1e-10  # nearly parallel, under the 1e-8 threshold
    n[0:5] = [[0.95, 0.0, np.sqrt(1 - 0.95**2)]] * 5  # |n_x| >= 0.9: the fallback starts from y
    return n, tg


def test_frame_from_normal_tangent_reproduces_stage():
    n, tg = _frame_inputs()
    t, b = brdf.frame_from_normal_tangent(n, tg)
    assert isinstance(t, np.ndarray) and isinstance(b, np.ndarray)
    t_ref, b_ref = stage_frame_reference(n.copy(), tg.copy())
    np.testing.assert_array_equal(t, t_ref)
    np.testing.assert_array_equal(b, b_ref)
    _check_frame(t, b, n, 1e-12)
    # Where the guess has a usable tangent, t lies in the plane of n and t_guess, on its side.
    ok = slice(45, None)
    assert np.all(np.sum(t[ok] * tg[ok], axis=1) > 0)
    assert_close(np.sum(np.cross(n[ok], tg[ok]) * t[ok], axis=1), np.zeros(155), rtol=0, atol=1e-12)


def test_frame_from_normal_tangent_jax_matches_numpy_and_has_finite_gradients():
    n, tg = _frame_inputs()
    t, b = brdf.frame_from_normal_tangent(jnp.asarray(n), jnp.asarray(tg))
    assert isinstance(t, jax.Array)
    t_np, b_np = brdf.frame_from_normal_tangent(n, tg)
    assert_close(t, t_np, rtol=0, atol=1e-12)
    assert_close(b, b_np, rtol=0, atol=1e-12)
    jitted = jax.jit(brdf.frame_from_normal_tangent)(jnp.asarray(n), jnp.asarray(tg))
    assert_close(jitted[0], t, rtol=0, atol=1e-12)

    def total(n, tg):
        t, b = brdf.frame_from_normal_tangent(n, tg)
        w = jnp.arange(1.0, 4.0, dtype=t.dtype)[None]
        return jnp.sum(t * w) + jnp.sum(b * (w + 1.0))

    grad = fjit(jax.grad(total, argnums=(0, 1)))
    assert_finite(grad(jnp.asarray(n), jnp.asarray(tg)))
    n32 = jnp.asarray(n, jnp.float32)
    assert_finite(grad(n32, jnp.asarray(tg, jnp.float32)))

"""Pattern captures (stage/_patterns.py): the weighted sum of OLAT frames against an explicit sum and
closed forms, gradient patterns against Ma et al. 2007's ratio, the sensor per pattern frame, the direct
chunked simulation against summing the OLAT capture, and bad input."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdf
import stage
import stage._patterns as patterns_module

from ..helpers import REFUSED
from ..scenes import plane, uv_sphere


def _material(P, rho=0.6, f0=0.04, alpha=0.25):
    f = lambda v, c: jnp.full((P, c), v, jnp.float32)  # noqa: E731
    return brdf.lambert_ggx(f(rho, 3), f(f0, 1), f(alpha, 1))


@pytest.fixture(scope="module")
def sphere():
    mesh = uv_sphere(radius=50.0, n_lat=16, n_lon=32)
    surf = stage.texel_samples(mesh, 16)
    rig = stage.geodesic_dome(1)  # 42 distant lights
    cam = stage.look_at((0.0, 0.0, 1000.0), fov_deg=8, width=64, height=64)
    lv = stage.light_visibility(mesh, surf, rig)
    cv = stage.camera_visibility(mesh, surf, [cam])
    cap = stage.simulate(surf, rig, [cam], _material(surf.num_samples), lv, cv)
    return dict(mesh=mesh, surf=surf, rig=rig, cam=cam, lv=lv, cv=cv, cap=cap)


def test_capture_patterns_is_the_weighted_sum_of_the_olat_frames(sphere, key):
    cap = sphere["cap"]
    # A sensed capture: read noise leaves masked-out (shadowed) observations non-zero, so the test also
    # checks that they count 0 as the contract says.
    noisy = stage.sense(cap, stage.Sensor(exposure=200.0, read_noise=2.0), key)
    W = np.random.default_rng(0).uniform(0.0, 1.0, (7, cap.rig.num_lights))
    pc = stage.capture_patterns(noisy, W)
    rad = np.where(np.asarray(noisy.mask)[..., None], np.asarray(noisy.radiance, np.float64), 0.0)
    V, L, P, C = rad.shape
    want = np.zeros((V, 7, P, C))
    for k in range(7):
        for lt in range(L):
            want[:, k] += W[k, lt] * rad[:, lt]
    assert pc.radiance.shape == (V, 7, P, C)
    # float32 radiance summed over 42 lights: relative rounding ~ 42 eps32.
    np.testing.assert_allclose(np.asarray(pc.radiance), want, rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(np.asarray(pc.valid), np.asarray(noisy.mask).any(axis=1))
    # A float16 capture is summed in float32: only its own rounding (2^-11 relative per frame) is left.
    half = noisy.astype(jnp.float16)
    want16 = np.einsum("kl,vlpc->vkpc", W, np.where(np.asarray(half.mask)[..., None],
                                                    np.asarray(half.radiance, np.float64), 0.0))
    got16 = stage.capture_patterns(half, W)
    assert got16.radiance.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(got16.radiance), want16, rtol=1e-5, atol=1e-6)
    assert np.asarray(pc.valid).sum() > 50
    np.testing.assert_array_equal(np.asarray(pc.mask), np.broadcast_to(np.asarray(pc.valid)[:, None], (V, 7, P)))


def test_identity_patterns_give_back_the_olat_capture(sphere):
    cap = sphere["cap"]
    L = cap.rig.num_lights
    pc = stage.capture_patterns(cap, np.eye(L))
    want = np.where(np.asarray(cap.mask)[..., None], np.asarray(cap.radiance), 0.0)
    np.testing.assert_array_equal(np.asarray(pc.radiance), want)
    # The simulator already zeroes what its mask leaves out, so this is the capture itself.
    np.testing.assert_array_equal(np.asarray(pc.radiance), np.asarray(cap.radiance))


def test_full_on_lambertian_matches_the_closed_form():
    # Distant lights of irradiance E = 1 spread evenly (Fibonacci) over the sphere: light l stands for a
    # cell of 4 pi / L sr, so all lights at weight 1 are a uniform sky of radiance L_sky = E L / (4 pi).
    # A Lambertian surface of albedo rho reflects L_o = (rho / pi) * pi * L_sky = rho E L / (4 pi).
    mesh = plane(size=20.0, n=2)
    surf = stage.texel_samples(mesh, 4)
    L = 4000
    rig = stage.fibonacci_sphere(L)
    cam = stage.look_at((0.0, 1000.0, 0.0), up=(0.0, 0.0, -1.0), fov_deg=5, width=32, height=32)
    P = surf.num_samples
    lv = np.ones((P, L), bool)  # an open plane: nothing shadows it (lights below have cos_i < 0)
    cv = stage.camera_visibility(mesh, surf, [cam])
    rho = jnp.asarray([[0.2, 0.5, 0.8]] * P, jnp.float32)
    pc = stage.simulate_patterns(surf, rig, [cam], brdf.Lambert(rho), lv, cv, np.ones((1, L)))
    got = np.asarray(pc.radiance, np.float64)[0, 0]
    want = np.asarray(rho, np.float64) * L / (4 * np.pi)
    assert np.all(np.asarray(pc.valid))
    # The Fibonacci quadrature of the clamped cosine with 4000 points is good to ~1e-4 (its kink at the
    # horizon sets the error); 1e-3 leaves room.
    np.testing.assert_allclose(got, want, rtol=1e-3)


def test_gradient_patterns_reproduce_ma_et_al_ratio_on_a_dense_rig():
    mesh = uv_sphere(radius=50.0, n_lat=16, n_lon=32)
    surf = stage.texel_samples(mesh, 16)
    rig = stage.geodesic_dome(3)  # 642 lights, ~8 degrees apart
    cam = stage.look_at((0.0, 0.0, 1000.0), fov_deg=8, width=64, height=64)
    lv = stage.light_visibility(mesh, surf, rig, packed=True)
    cv = stage.camera_visibility(mesh, surf, [cam])
    P = surf.num_samples
    cap = stage.simulate(surf, rig, [cam], brdf.Lambert(jnp.full((P, 3), 0.7, jnp.float32)), lv, cv)
    G = stage.gradient_patterns(rig)
    assert G.shape == (4, rig.num_lights)
    assert float(jnp.max(G)) == 1.0 and float(jnp.min(G)) >= 0.0
    pc = stage.capture_patterns(cap, G)
    seen = np.asarray(pc.valid[0])
    assert seen.sum() > 100
    I = np.asarray(pc.radiance, np.float64)[0].mean(-1)  # [4, P]
    n = np.asarray(surf.normal, np.float64)
    ratio = I[1:, seen] / I[0, seen]
    # Ma et al. 2007 eq. 4 for a Lambertian surface; 642 lights stand in for the sphere (~1e-3).
    np.testing.assert_allclose(ratio.T, 0.5 + n[seen] / 3.0, atol=3e-3)
    nd = np.asarray(stage.diffuse_normals(pc.radiance[0]), np.float64)[seen]
    err = np.degrees(np.arccos(np.clip(np.sum(nd * n[seen], 1), -1, 1)))
    assert err.max() < 1.0, err.max()
    # The same patterns as stage.gradient_weights, up to the one scale that makes the largest weight 1.
    gw = np.asarray(stage.gradient_weights(rig), np.float64)[..., 0]
    np.testing.assert_allclose(np.asarray(G, np.float64) * gw.max(), gw, rtol=1e-5, atol=1e-9)
    # The complements: P_i + its complement = the full-on pattern.
    Gc = np.asarray(stage.gradient_patterns(rig, complement=True), np.float64)
    assert Gc.shape == (6, rig.num_lights) and Gc.max() == pytest.approx(1.0) and Gc.min() >= 0
    full = Gc[:3] + Gc[3:]  # each row is the full-on pattern at the complemented set's scale
    np.testing.assert_allclose(full, np.broadcast_to(full[0], full.shape), rtol=1e-6)
    np.testing.assert_allclose((Gc[0] + Gc[3]) / (Gc[0] + Gc[3]).max(), np.asarray(G[0]), rtol=1e-5)


def test_sense_patterns_noise_is_per_pattern_frame(sphere, key):
    # Shot noise of one exposure per pattern: in radiance units Var = I_k / exposure (gain 1, wb 1).
    rig, cam = sphere["rig"], sphere["cam"]
    K, P, exposure = 3, 20000, 50.0
    levels = np.asarray([0.5, 4.0, 40.0])  # 25 to 2000 photo-electrons
    rad = jnp.asarray(np.broadcast_to(levels[None, :, None, None], (1, K, P, 3)), jnp.float32)
    W = np.full((K, rig.num_lights), 0.5)
    pc = stage.PatternCapture(radiance=rad, valid=jnp.ones((1, P), bool), patterns=jnp.asarray(W, jnp.float32),
                              rig=rig, cameras=(cam,))
    out = stage.sense_patterns(pc, stage.Sensor(exposure=exposure, shot_noise=True), key)
    assert out.sensor is not None and out.saturated.shape == (1, K, P) and not np.any(np.asarray(out.saturated))
    x = np.asarray(out.radiance, np.float64)[0].reshape(K, -1)
    n = x.shape[1]
    var = x.var(axis=1, ddof=1)
    want = levels / exposure
    # The sample variance of n near-Gaussian draws has relative standard error sqrt(2 / (n - 1)) (~0.6% for
    # n = 60000; Poisson's excess kurtosis 1/e adds less than that at e >= 25): 5 standard errors.
    rel_se = np.sqrt(2.0 / (n - 1) + 1.0 / (levels * exposure * n))
    assert np.all(np.abs(var / want - 1.0) < 5 * rel_se), (var / want - 1.0, rel_se)
    # The mean is the signal: standard error sqrt(Var / n).
    assert np.all(np.abs(x.mean(axis=1) - levels) < 5 * np.sqrt(want / n)), x.mean(axis=1) - levels
    # Saturation is per pattern measurement.
    sat = stage.sense_patterns(pc, stage.Sensor(exposure=exposure, full_well=1000.0), key)
    np.testing.assert_array_equal(np.asarray(sat.saturated)[0].all(axis=1), [False, False, True])
    assert not np.asarray(sat.mask)[0, 2].any() and np.asarray(sat.mask)[0, :2].all()


@pytest.mark.parametrize("bad, what", [
    (lambda L: np.full((2, L), 1.5), "in \\[0, 1\\]"),
    (lambda L: np.full((2, L), -0.1), "in \\[0, 1\\]"),
    (lambda L: np.full((2, L + 1), 0.5), "lights"),
    (lambda L: np.where(np.eye(2, L) > 0, np.nan, 0.5), "finite"),
    (lambda L: np.full(L, 0.5), "shape"),
    (lambda L: np.zeros((0, L)), "shape"),
    (lambda L: np.array([["a"] * L]), "numbers"),
])
def test_bad_patterns_are_refused_naming_patterns(sphere, bad, what):
    cap = sphere["cap"]
    L = cap.rig.num_lights
    with pytest.raises(ValueError, match="patterns") as err:
        stage.capture_patterns(cap, bad(L))
    assert err.match(what)
    with pytest.raises(ValueError, match="patterns"):
        stage.simulate_patterns(sphere["surf"], sphere["rig"], [sphere["cam"]], _material(sphere["surf"].num_samples),
                                sphere["lv"], sphere["cv"], bad(L))


def test_capture_patterns_is_differentiable_in_the_patterns(sphere):
    # What learning the patterns needs (relight.patterns): jit and grad through the weighted sum.
    cap = sphere["cap"]
    W0 = jnp.full((3, cap.rig.num_lights), 0.5, jnp.float32)
    loss = jax.jit(lambda W: jnp.sum(stage.capture_patterns(cap, W).radiance ** 2))
    g = jax.grad(loss)(W0)
    assert g.shape == W0.shape and np.all(np.isfinite(np.asarray(g)))
    # d/dW[k, l] of sum (sum_l W x)^2 = 2 sum I_k x_l: against the explicit form.
    x = np.asarray(cap.radiance, np.float64)
    I = np.einsum("kl,vlpc->vkpc", np.asarray(W0, np.float64), x)
    np.testing.assert_allclose(np.asarray(g), 2 * np.einsum("vkpc,vlpc->kl", I, x), rtol=1e-4)


@pytest.mark.parametrize("polarization", [None, "cross"])
def test_simulate_patterns_equals_summing_the_olat_capture(sphere, polarization):
    s = sphere
    W = np.random.default_rng(1).uniform(0.0, 1.0, (5, s["rig"].num_lights))
    mat = _material(s["surf"].num_samples)
    olat = stage.simulate(s["surf"], s["rig"], [s["cam"]], mat, s["lv"], s["cv"], polarization=polarization)
    want = stage.capture_patterns(olat, W)
    got = stage.simulate_patterns(s["surf"], s["rig"], [s["cam"]], mat, s["lv"], s["cv"], W, light_chunk=16,
                                  sample_chunk=100, polarization=polarization)
    scale = float(np.max(np.asarray(want.radiance)))
    # float32 sums over 42 lights in another order (chunks of 16 instead of one einsum).
    np.testing.assert_allclose(np.asarray(got.radiance), np.asarray(want.radiance), rtol=1e-5, atol=1e-6 * scale)
    np.testing.assert_array_equal(np.asarray(got.valid), np.asarray(want.valid))
    np.testing.assert_array_equal(np.asarray(got.patterns), np.asarray(want.patterns))


def test_simulate_patterns_never_builds_the_olat_capture(sphere, monkeypatch):
    s = sphere
    P, L = s["surf"].num_samples, s["rig"].num_lights
    W = np.random.default_rng(2).uniform(0.0, 1.0, (4, L))
    mat = _material(P)
    seen = []
    real = patterns_module._chunks

    def spy(*args, **kwargs):
        for item in real(*args, **kwargs):
            seen.append(tuple(item[3].shape))
            yield item

    monkeypatch.setattr(patterns_module, "_chunks", spy)
    results = []
    for lc, sc in ((8, 64), (32, 1 << 14)):
        seen.clear()
        results.append(np.asarray(stage.simulate_patterns(s["surf"], s["rig"], [s["cam"]], mat, s["lv"], s["cv"], W,
                                                          light_chunk=lc, sample_chunk=sc).radiance))
        # Every block of OLAT radiance alive at once is at most light_chunk x sample_chunk x C.
        assert seen and max(x[0] for x in seen) <= lc and max(x[1] for x in seen) <= min(sc, P)
        assert len(seen) == -(-L // lc) * -(-P // min(sc, P))
    # Two chunk schedules, one answer (float32 summation order only).
    scale = float(np.max(results[0]))
    np.testing.assert_allclose(results[0], results[1], rtol=1e-5, atol=1e-6 * scale)
    # Without the spy, the output's shape follows from the inputs alone: [V, K, P, C], no light axis.
    assert results[0].shape == (1, 4, P, 3)


def test_pattern_capture_validates_its_shapes(sphere):
    cap = sphere["cap"]
    pc = stage.capture_patterns(cap, np.full((2, cap.rig.num_lights), 0.5))
    with pytest.raises(REFUSED):  # the annotation's sample axis, or the check naming valid
        stage.PatternCapture(pc.radiance, pc.valid[:, :3], pc.patterns, pc.rig, pc.cameras)
    with pytest.raises(ValueError, match="patterns"):
        stage.PatternCapture(pc.radiance, pc.valid, pc.patterns[:, :3], pc.rig, pc.cameras)
    one = pc.select([1])
    assert one.shape[1] == 1 and one.num_patterns == 1
    np.testing.assert_array_equal(np.asarray(one.radiance[:, 0]), np.asarray(pc.radiance[:, 1]))


def test_simulate_patterns_is_differentiable_like_simulate(sphere):
    # jax.grad through the direct simulation (the traced path: jnp accumulation over chunks) equals the
    # gradient through summing the OLAT capture, for the albedo and the pattern weights.
    s = sphere
    P, L = s["surf"].num_samples, s["rig"].num_lights
    W = jnp.asarray(np.random.default_rng(4).uniform(0.0, 1.0, (3, L)), jnp.float32)
    rho = jnp.full((P, 3), 0.5, jnp.float32)
    args = (s["surf"], s["rig"], [s["cam"]])

    def direct(rho, W):
        return jnp.sum(stage.simulate_patterns(*args, brdf.Lambert(rho), s["lv"], s["cv"], W, light_chunk=16,
                                               sample_chunk=128).radiance ** 2)

    def summed(rho, W):
        return jnp.sum(stage.capture_patterns(stage.simulate(*args, brdf.Lambert(rho), s["lv"], s["cv"]), W).radiance
                       ** 2)

    # One jitted program for both gradients (the chunks are traced either way), not thousands of eager operations.
    g1, g2 = jax.jit(lambda r, w: (jax.grad(direct, argnums=(0, 1))(r, w), jax.grad(summed, argnums=(0, 1))(r, w)))(
        rho, W)
    for a, b in zip(g1, g2, strict=True):
        assert np.all(np.isfinite(np.asarray(a)))
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-4, atol=1e-6 * float(np.max(np.abs(b))))

"""Learned lighting patterns (relight.patterns; Kang et al. 2018): lumitexels
against stage.simulate, the encoder against stage.capture_patterns, bounded
weights, training progress, the decoder start + fit_patterns recovery, and
finite gradients at the parameter edges."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdf
import relight.patterns as rp
import stage

EYE = (0.0, 0.0, 1000.0)
# One compiled program per shape instead of hundreds of eagerly dispatched operations.
simulate = eqx.filter_jit(rp.simulate_lumitexels)


@pytest.fixture(scope="module")
def dome():
    return stage.geodesic_dome(1)  # 42 distant lights: small and fast


@pytest.fixture(scope="module")
def camera():
    return stage.look_at(EYE, fov_deg=20, width=64, height=64)


def _config(**kw):
    base = dict(steps=300, batch=64, lr=3e-3, warmup=20, width=32, depth=2, seed=3, grid=())
    base.update(kw)
    return rp.TrainConfig(**base)


# A two-roughness grid: the grid decoder's code path at a fraction of ALPHA_GRID's compile time.
GRID2 = (0.1, 0.3)


def test_lumitexels_equal_stage_simulate(camera):
    """The data path (incident_light / to_local / reflected_radiance_lights per sample)
    equals stage.simulate of the same Lambert + GGX samples (its chunked scheduling), on a
    near-field dome (inverse-square irradiance)."""
    rig = stage.geodesic_dome(2, near_field=True)
    lumi = simulate(jax.random.PRNGKey(0), rig, camera.center, 64)
    mat = brdf.lambert_ggx(lumi.rho_d, lumi.rho_s[:, None], lumi.alpha[:, None])
    cap = stage.simulate(rp.as_surface(lumi), rig, [camera], mat, np.ones((64, rig.num_lights), bool),
                         np.ones((1, 64), bool))
    ref = np.swapaxes(np.asarray(cap.radiance[0]), 0, 1)
    got = np.asarray(lumi.radiance)
    # float32 both ways, different operation order: relative to the largest value.
    assert np.max(np.abs(got - ref)) <= 1e-5 * np.max(ref)
    assert np.array_equal(np.asarray(lumi.visible), np.swapaxes(np.asarray(cap.mask[0]), 0, 1))


def test_encoder_equals_capture_patterns(camera):
    """The encoder's measurement (einsum of sigmoid weights with lumitexels) equals
    stage.capture_patterns of the same lumitexels as an OLAT capture (independent path),
    with random occluders (shadowed lights count 0 in both)."""
    rig = stage.geodesic_dome(2, near_field=True)
    lumi = simulate(jax.random.PRNGKey(1), rig, camera.center, 48, rp.ParameterRanges(occlusion=0.5))
    # The trained fixture's model shapes (its random initialisation compiles once for both).
    model = rp.PatternAutoencoder(jax.random.PRNGKey(2), 32, rig.num_lights, width=64, depth=2, grid=GRID2)
    y = np.asarray(eqx.filter_jit(lambda m, r: m.measure(r))(model, lumi.radiance))  # [N, K, C]
    pc = stage.capture_patterns(rp.as_capture(lumi, rig, camera), model.patterns)
    ref = np.transpose(np.asarray(pc.radiance[0]), (1, 0, 2))
    assert y.shape == ref.shape == (48, 32, 3)
    np.testing.assert_allclose(y, ref, rtol=1e-5, atol=1e-6 * np.max(ref))


def test_grid_features_exact_at_grid_roughness(dome, camera):
    """Closed form: for noise-free samples whose alpha is a grid roughness, that
    grid entry's least-squares solve returns the true (rho_d, F0) with ~0 residual
    (the model rho_d white + F0 A + B is exact there), in float64."""
    grid = rp.ALPHA_GRID
    n = 2 * len(grid)
    key = jax.random.PRNGKey(4)
    rho_d, rho_s, _ = rp.sample_materials(key, n, rp.TEST_RANGES, jnp.float64)
    alpha = jnp.asarray(np.tile(grid, 2), jnp.float64)
    pos, normal, wo = rp.sample_geometry(jax.random.PRNGKey(5), n, camera.center, rp.TEST_RANGES, jnp.float64)
    t, b = brdf.orthonormal_basis(normal)
    rad, white, lit = eqx.filter_jit(rp.lumitexels)(dome, pos, normal, t, b, wo, rho_d, rho_s, alpha)
    bases = eqx.filter_jit(rp.specular_bases)(dome, pos, normal, t, b, wo, lit, grid)
    j = np.tile(np.arange(len(grid)), 2)  # sample i has the roughness grid[j[i]]
    idx = np.arange(n)
    recon = (rho_d[:, None, :] * white + rho_s[:, None, None] * bases[idx, :, :, 2 * j]
             + bases[idx, :, :, 2 * j + 1])
    np.testing.assert_allclose(np.asarray(recon), np.asarray(rad), rtol=1e-9, atol=1e-12 * float(jnp.max(rad)))
    W = jax.nn.sigmoid(2.0 * jax.random.normal(jax.random.PRNGKey(6), (12, dome.num_lights), jnp.float64))
    f = jax.jit(rp.grid_features)(rp.measure(W, rad), rp.measure(W, white), jnp.einsum("kl,nlcb->nkcb", W, bases))
    got = np.asarray(f).reshape(n, len(grid), 5)[idx, j]
    np.testing.assert_allclose(got[:, :3], np.asarray(rho_d), rtol=1e-5)
    np.testing.assert_allclose(got[:, 3], np.asarray(rho_s), rtol=1e-4)
    assert np.all(got[:, 4] < np.log(1e-4) + 0.01)  # relative residual ~0 (the feature's 1e-4 floor)


SENSOR = stage.Sensor(exposure=2000.0, read_noise=5.0, shot_noise=True)
# The one training configuration of the tests (one compilation, shared through the make_optimizer cache).
TRAINED = dict(steps=300, batch=64, width=64, ranges=rp.TEST_RANGES, grid=GRID2)


@pytest.fixture(scope="module")
def trained():
    """A small model trained once for several tests: 32 patterns on a 162-light dome, a
    two-roughness grid decoder (64 wide), 300 steps of 64 test-range lumitexels."""
    rig = stage.geodesic_dome(2)
    model, hist = rp.train(rig, EYE, 32, SENSOR, _config(**TRAINED), log_every=30)
    return rig, model, hist


def test_weights_stay_in_unit_interval(trained):
    """After 300 training steps every weight is finite and in [0, 1] and stage accepts the
    patterns; logits driven to +-1e4 (far past any step) still give weights in [0, 1]."""
    rig, model, _ = trained
    W = np.asarray(model.patterns)
    assert np.all(np.isfinite(W)) and W.min() >= 0.0 and W.max() <= 1.0
    stage.check_patterns(W, rig.num_lights)
    wild = eqx.tree_at(lambda m: m.logits, model, 1e4 * jnp.sign(model.logits - jnp.median(model.logits)))
    Ww = np.asarray(wild.patterns)
    assert np.all(np.isfinite(Ww)) and Ww.min() == 0.0 and Ww.max() == 1.0
    stage.check_patterns(Ww, rig.num_lights)


def test_training_lowers_loss(trained):
    """300 steps cut the loss (first 30 steps' mean against the last 30's) by at least 2x."""
    _, _, hist = trained
    assert all(np.isfinite(h["loss"]) for h in hist)
    assert hist[-1]["loss"] < hist[0]["loss"] / 2.0, [round(h["loss"], 3) for h in hist]


def test_training_is_deterministic(trained):
    """The same configuration and seed give the same loss history and weights, bit for bit."""
    rig, model, hist = trained
    again, hist2 = rp.train(rig, EYE, 32, SENSOR, _config(**TRAINED), log_every=30)
    assert hist2 == hist
    assert np.array_equal(np.asarray(again.logits), np.asarray(model.logits))


def test_save_load_round_trip(dome, tmp_path):
    # test_no_nan_gradients_at_edges' model shapes (grid decoder included; one initialisation compile for both).
    model = rp.PatternAutoencoder(jax.random.PRNGKey(0), 8, dome.num_lights, width=16, depth=2, grid=GRID2)
    rp.save_model(tmp_path / "m", model, dome, metadata={"note": "test"})
    back, meta = rp.load_model(tmp_path / "m")
    assert meta["note"] == "test"
    for x, y in zip(jax.tree_util.tree_leaves(eqx.filter(model, eqx.is_array)),
                    jax.tree_util.tree_leaves(eqx.filter(back, eqx.is_array)), strict=True):
        assert np.array_equal(np.asarray(x), np.asarray(y))
    assert (tmp_path / "m.patterns.json").is_file()


def _edge_lumitexels(rig):
    """Samples at the parameter edges: alpha at brdf's floor, F0 = 0, a grazing normal (89.9 deg from wo)."""
    n = 4
    pos = jnp.zeros((n, 3), jnp.float32)
    wo = jnp.tile(jnp.asarray([[0.0, 0.0, 1.0]], jnp.float32), (n, 1))
    g = np.deg2rad(89.9)
    normal = jnp.asarray([[0, 0, 1], [np.sin(g), 0, np.cos(g)], [0, np.sin(g), np.cos(g)], [0, 0, 1]], jnp.float32)
    rho_d = jnp.asarray([[0.5, 0.5, 0.5], [0.2, 0.3, 0.4], [0.0, 0.0, 0.0], [0.9, 0.9, 0.9]], jnp.float32)
    rho_s = jnp.asarray([0.0, 0.04, 0.04, 0.0], jnp.float32)
    alpha = jnp.asarray([float(brdf.ALPHA_MIN), float(brdf.ALPHA_MIN), rp.ALPHA_DECODE_MIN, 1.0], jnp.float32)
    return pos, normal, wo, rho_d, rho_s, alpha


def test_no_nan_gradients_at_edges(dome):
    """Finite loss and gradients (model weights with the grid decoder, and lumitexels
    w.r.t. the material and the normal) at alpha = brdf.ALPHA_MIN, F0 = 0, rho_d = 0
    and grazing normals."""
    pos, normal, wo, rho_d, rho_s, alpha = _edge_lumitexels(dome)
    t, b = brdf.orthonormal_basis(normal)
    # One compiled program instead of hundreds of eagerly dispatched operations.
    rad, white, lit = eqx.filter_jit(rp.lumitexels)(dome, pos, normal, t, b, wo, rho_d, rho_s, alpha)
    lumi = rp.Lumitexels(radiance=rad, white=white, visible=lit, rho_d=rho_d, rho_s=rho_s, alpha=alpha,
                         position=pos, normal=normal, tangent=t, bitangent=b, wo=wo)
    model = rp.PatternAutoencoder(jax.random.PRNGKey(0), 8, dome.num_lights, width=16, depth=2, grid=GRID2)
    sensor = stage.Sensor(exposure=2000.0, read_noise=5.0, shot_noise=True)

    def f(m):
        return rp.total_loss(rp.loss_terms(m, lumi, jax.random.PRNGKey(1), sensor, dome), 0.5)

    loss, grads = eqx.filter_jit(eqx.filter_value_and_grad(f))(model)
    assert np.isfinite(float(loss))
    assert all(np.all(np.isfinite(np.asarray(g))) for g in jax.tree_util.tree_leaves(grads))

    def g(params):
        rd, rs, al, nrm = params
        nrm = brdf.safe_normalize(nrm)
        tt, bb = brdf.orthonormal_basis(nrm)
        r, _, _ = rp.lumitexels(dome, pos, nrm, tt, bb, wo, rd, rs, al)
        return jnp.sum(jnp.arcsinh(r))

    grads = jax.jit(jax.grad(g))((rho_d, rho_s, alpha, normal))
    assert all(np.all(np.isfinite(np.asarray(x))) for x in grads)


def test_decoder_start_and_fit_patterns_recover_ggx(camera, trained):
    """32 learned patterns (the ``trained`` fixture), noise-free GGX samples: the
    decoder's start refined by relight.fitting.fit_patterns recovers rho_d to a
    median 0.5% and alpha to a median 2%."""
    rig, model, _ = trained
    lumi = simulate(jax.random.PRNGKey(7), rig, camera.center, 32, rp.TEST_RANGES)
    pc = stage.capture_patterns(rp.as_capture(lumi, rig, camera), model.patterns)
    surf = rp.as_surface(lumi)
    vis = np.ones((32, rig.num_lights), bool)
    fit = rp.fit_learned(pc, surf, vis, model)
    e_rho = np.mean(np.abs(np.asarray(fit.rho_d) - np.asarray(lumi.rho_d)) / np.asarray(lumi.rho_d), axis=1)
    e_a = np.abs(np.asarray(fit.alpha)[:, 0] - np.asarray(lumi.alpha)) / np.asarray(lumi.alpha)
    assert np.median(e_rho) < 0.005 and np.median(e_a) < 0.02, (np.median(e_rho), np.median(e_a))

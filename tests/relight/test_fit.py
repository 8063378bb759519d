import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
import pytest

import brdf
import relight
import stage
from relight import fit
from relight.fitting import FitOptions

from ..scenes import uv_sphere


@pytest.fixture(scope="module")
def scene():
    mesh = uv_sphere(radius=50.0, n_lat=24, n_lon=48)
    surface = stage.texel_samples(mesh, 24)
    rig = stage.geodesic_dome(2)  # 162 distant lights, ~17 degrees apart
    cam = stage.look_at((0.0, 0.0, 1000.0), fov_deg=10, width=256, height=256)
    lv = stage.light_visibility(mesh, surface, rig)
    cv = stage.camera_visibility(mesh, surface, [cam])
    # Keep samples facing the camera well (cos_o > 0.3) so every lobe is observed.
    p = np.asarray(surface.position)
    keep = np.nonzero(cv[0] & (p[:, 2] / 50.0 > 0.3))[0][::3]
    surface = surface.subset(keep)
    return surface, rig, cam, lv[keep], cv[:, keep]


def _truth(n, seed=0):
    rng = np.random.default_rng(seed)
    rho = rng.uniform(0.1, 0.8, (n, 3))
    f0 = rng.uniform(0.02, 0.08, (n, 1))
    alpha = rng.uniform(0.15, 0.6, (n, 1))
    return (jnp.asarray(x, jnp.float32) for x in (rho, f0, alpha))


def test_noise_free_recovery(scene):
    surface, rig, cam, lv, cv = scene
    rho, f0, alpha = _truth(surface.num_samples)
    cap = stage.simulate(surface, rig, [cam], brdf.lambert_ggx(rho, f0, alpha), lv, cv)
    # Tight tolerances (the defaults stop at the noise floor of real data).
    f = fit(cap, surface, model="ggx", loss="cauchy", options=FitOptions(rtol=1e-6, atol=1e-7))
    assert not np.any(np.asarray(f.failed))
    # The model is the simulator's: recovery is limited by float32 and the solver tolerance.
    np.testing.assert_allclose(np.asarray(f.rho_d), np.asarray(rho), rtol=2e-3)
    np.testing.assert_allclose(np.asarray(f.alpha[:, :1]), np.asarray(alpha), rtol=1e-2)
    np.testing.assert_allclose(np.asarray(f.f0), np.asarray(f0), rtol=2e-2)
    assert float(np.max(np.asarray(f.residual))) < 1e-4


def test_one_percent_noise(scene):
    surface, rig, cam, lv, cv = scene
    rho, f0, alpha = _truth(surface.num_samples, seed=1)
    cap = stage.simulate(surface, rig, [cam], brdf.lambert_ggx(rho, f0, alpha), lv, cv)
    noise = 1 + 0.01 * np.random.default_rng(2).standard_normal(cap.radiance.shape)
    cap = stage.Capture(cap.radiance * jnp.asarray(noise, jnp.float32), cap.mask, cap.rig, cap.cameras)
    f = fit(cap, surface, model="ggx", loss="cauchy")
    err_rho = np.abs(np.asarray(f.rho_d) - np.asarray(rho)) / np.asarray(rho)
    err_alpha = np.abs(np.asarray(f.alpha[:, :1]) - np.asarray(alpha)) / np.asarray(alpha)
    # ~60 lit lights x 1% noise: the albedo is averaged down well below 1%; roughness is
    # set by the few lights inside the lobe, so it is noisier (issue 7 sets < 5% on Light Stage X).
    assert np.median(err_rho) < 0.01
    assert np.median(err_alpha) < 0.1


def test_no_nan_when_a_sample_has_no_data(scene):
    surface, rig, cam, lv, cv = scene
    rho, f0, alpha = _truth(surface.num_samples, seed=3)
    cap = stage.simulate(surface, rig, [cam], brdf.lambert_ggx(rho, f0, alpha), lv, cv)
    mask = np.asarray(cap.mask).copy()
    mask[:, :, 0] = False  # sample 0: every observation invalid
    rad = np.asarray(cap.radiance).copy()
    rad[:, :, 1] = 0.0  # sample 1: black (albedo 0 is at the bound)
    cap = stage.Capture(jnp.asarray(rad), jnp.asarray(mask), cap.rig, cap.cameras)
    f = fit(cap, surface, model="ggx", loss="cauchy")
    for leaf in (f.rho_d, f.f0, f.alpha, f.residual):
        assert np.all(np.isfinite(np.asarray(leaf)))
    assert bool(f.failed[0])
    assert float(np.max(np.asarray(f.rho_d)[1])) < 0.01


def test_mismatched_capture_is_refused(scene):
    surface, rig, cam, lv, cv = scene
    rho, f0, alpha = _truth(surface.num_samples)
    cap = stage.simulate(surface, rig, [cam], brdf.lambert_ggx(rho, f0, alpha), lv, cv)
    with pytest.raises(ValueError, match="samples"):
        fit(cap, surface.subset(np.arange(3)), model="ggx", loss="cauchy")


def _noisy(cap, sigma, seed):
    noise = 1 + sigma * np.random.default_rng(seed).standard_normal(cap.radiance.shape)
    return stage.Capture(cap.radiance * jnp.asarray(noise, jnp.float32), cap.mask, cap.rig, cap.cameras)


def _tilted(surface, deg, seed):
    """The surface with its shading normals tilted by ``deg`` in random azimuths
    (the truth for a normal fit; the fit starts from the untilted frame)."""
    rng = np.random.default_rng(seed)
    phi = rng.uniform(0, 2 * np.pi, surface.num_samples)
    th = np.deg2rad(deg)
    local = np.stack([np.sin(th) * np.cos(phi), np.sin(th) * np.sin(phi), np.full_like(phi, np.cos(th))], 1)
    T, B, N = (np.asarray(x) for x in (surface.tangent, surface.bitangent, surface.normal))
    n = local[:, :1] * T + local[:, 1:2] * B + local[:, 2:3] * N
    maps = relight.material_maps(surface, 0.5, normal=n)
    return maps.frame(surface)


def test_normals_recovered_from_a_tilted_start(scene):
    surface, rig, cam, lv, cv = scene
    truth_surface = _tilted(surface, 8.0, seed=4)
    rho, f0, alpha = _truth(surface.num_samples, seed=5)
    cap = stage.simulate(truth_surface, rig, [cam], brdf.lambert_ggx(rho, f0, alpha), lv, cv)
    f = fit(cap, surface, model="ggx", loss="cauchy", normals=True)
    cos = np.sum(np.asarray(f.normal) * np.asarray(truth_surface.normal), 1)
    err_deg = np.rad2deg(np.arccos(np.clip(cos, -1, 1)))
    # Noise-free, the model is the simulator's: the normal is exact up to the
    # solver tolerance (issue 7's bar with 1% noise is 0.5 degree).
    assert np.median(err_deg) < 0.05 and np.max(err_deg) < 0.5
    np.testing.assert_allclose(np.asarray(f.alpha[:, :1]), np.asarray(alpha), rtol=2e-2)
    # The uncertainty of a noise-free fit is (near) zero; of every fitted parameter, finite.
    assert np.all(np.isfinite(np.asarray(f.uncertainty)))


def test_cauchy_loss_ignores_unmasked_shadows(scene):
    surface, rig, cam, lv, cv = scene
    rho, f0, alpha = _truth(surface.num_samples, seed=6)
    cap = stage.simulate(surface, rig, [cam], brdf.lambert_ggx(rho, f0, alpha), lv, cv)
    # 15% of the valid observations blacked out but left in the mask (cast shadows the mask missed).
    rng = np.random.default_rng(7)
    rad = np.asarray(cap.radiance).copy()
    mask = np.asarray(cap.mask)
    hit = mask & (rng.uniform(size=mask.shape) < 0.15)
    rad[hit] = 0.0
    bad = stage.Capture(jnp.asarray(rad), cap.mask, cap.rig, cap.cameras)
    err = {}
    for loss in ("l2", "cauchy"):
        f = fit(bad, surface, model="ggx", loss=loss)
        err[loss] = np.median(np.abs(np.asarray(f.rho_d) - np.asarray(rho)) / np.asarray(rho))
    # Plain L2 is dragged by the ~15% zeros (albedo biased low by ~that); Cauchy
    # weights them out (the measurement: 15% vs 0.8%).
    assert err["l2"] > 0.05
    assert err["cauchy"] < 0.02


def _half_lambertian(scene):
    """A 1%-noise capture whose even samples are pure Lambertian (no lobe, not even Schlick's grazing term) and
    odd ones Lambert + GGX; returns (capture, the Lambertian samples' mask)."""
    surface, rig, cam, lv, cv = scene
    P = surface.num_samples
    rho, f0, alpha = _truth(P, seed=8)
    lam = np.arange(P) % 2 == 0
    truth = relight.material_maps(surface, rho, f0 * 4, alpha, model=np.where(lam, 0, 2)).brdf(include_diffuse=True)
    return _noisy(stage.simulate(surface, rig, [cam], truth, lv, cv), 0.01, 9), lam


def test_model_ladder_picks_the_simplest_sufficient_rung(scene):
    surface = scene[0]
    P = surface.num_samples
    cap, lam = _half_lambertian(scene)
    calls = []
    f = fit(cap, surface, model="auto", options=FitOptions(progress=lambda *a: calls.append(a)))
    model = np.asarray(f.model)
    # The progress protocol (stage.Progress): a held-out trial per rung, then
    # the refits, which cover every sample once; each phase from 0 to its total;
    # the later rounds' stragglers on "(more steps)" phases, counts with no total.
    first, last = {}, {}
    for phase, done, total in calls:
        first.setdefault(phase, (done, total))
        last[phase] = (done, total)
    more = {p: last.pop(p) for p in list(last) if p.endswith(" (more steps)")}
    assert {f"fit {m} (held out)" for m in relight.MODELS[:4]} <= set(last)
    assert all(d == 0 for d, _ in first.values()) and all(d == t for d, t in last.values())
    # The lobes from the neighbours, after the refits: a phase over the Lambert samples it looks at.
    assert 0 < last.pop("lobes from neighbours")[1] <= P
    assert sum(t for phase, (_, t) in last.items() if "held out" not in phase) == P
    assert all(t is None and 0 < d <= P and p.removesuffix(" (more steps)") in last for p, (d, t) in more.items())
    # Lambertian samples: the Lambert rung (held-out error within noise of any richer rung).
    assert np.mean(model[lam] == relight.MODELS.index("lambert")) > 0.8
    # Glossy samples need a lobe: never Lambert; mostly the isotropic GGX the data came from.
    assert np.all(model[~lam] != 0)
    assert np.mean(model[~lam] >= relight.MODELS.index("ggx")) > 0.6
    assert np.all(np.asarray(f.heldout) > 0) and np.all(np.isfinite(np.asarray(f.heldout)))
    # The ladder leaves no lobe collapsed where a lobe was there to fit.
    assert not np.any(np.asarray(f.collapsed)[~lam])
    # A sample whose lobe is an extrapolated highlight goes one rung down, refitted, again while it is one
    # (docs/fit.md, "How", item 8). Here every GGX lobe is declared one (the closed-form cases of the flag:
    # tests/relight/test_extrapolated_highlights.py): GGX samples step to Blinn-Phong, whose lobes pass, so
    # they stop there, with Blinn-Phong's held-out error; the other samples keep their fit exactly.
    from relight.fitting import _driver
    from relight.materials import BLINN_PHONG, GGX

    real = _driver.extrapolated_highlights
    steps = []

    def every_ggx_lobe(u, lay, data, index, size):
        steps.append((lay.model, len(index)))
        return np.full(len(index), lay.model == GGX) if lay.model == GGX else real(u, lay, data, index, size)

    _driver.extrapolated_highlights = every_ggx_lobe
    try:
        g = fit(cap, surface, model="auto")
    finally:
        _driver.extrapolated_highlights = real
    was_ggx = model == GGX
    assert was_ggx.any() and (GGX, int(was_ggx.sum())) in steps
    assert np.all(np.asarray(g.model)[was_ggx] == BLINN_PHONG)
    assert np.array_equal(np.asarray(g.model)[~was_ggx], model[~was_ggx])
    np.testing.assert_array_equal(np.asarray(g.rho_d)[~was_ggx], np.asarray(f.rho_d)[~was_ggx])
    assert np.all(np.asarray(g.heldout)[was_ggx] != np.asarray(f.heldout)[was_ggx])


def test_auto_keeps_a_highlight_that_one_light_sees(scene):
    """A sharp GGX lobe (alpha 0.06: half its peak within 2 degrees of the half vector) under 162 lights
    17 degrees apart, 1% noise: the highlight covers one or two of a sample's lights, so the held-out
    observations rarely include it. ``model="auto"`` (the pooled prediction error, docs/fit.md, "How",
    item 8) must keep a lobe that reproduces it: at each such sample's brightest observation the fitted
    model's noise-free radiance is within 10% of the truth's, on at least 90% of those samples, and none
    goes to Lambert. (The rule before, separate held-out and training tests, kept Lambert or a lobe that
    misses the peak on MERL's acrylics: docs/measured_brdf.md.)"""
    surface, rig, cam, lv, cv = scene
    P = surface.num_samples
    rho, _, _ = _truth(P, seed=12)
    f0, alpha = jnp.full((P, 1), 0.3, jnp.float32), jnp.full((P, 1), 0.06, jnp.float32)
    true = stage.simulate(surface, rig, [cam], brdf.lambert_ggx(rho, f0, alpha), lv, cv)
    diffuse = stage.simulate(surface, rig, [cam], brdf.Lambert(rho), lv, cv)
    t, d = (np.asarray(c.radiance[0], np.float64).mean(-1) for c in (true, diffuse))  # [L, P]
    mask = np.asarray(true.mask[0])
    spec = np.where(mask, t - d, 0.0)
    lit = np.sum(spec > 0.1 * spec.max(0, keepdims=True), 0)  # lights within a tenth of the sample's peak
    sharp = (spec.max(0) > np.max(np.where(mask, d, 0.0), 0)) & (lit <= 2)
    assert sharp.sum() >= 20, sharp.sum()
    f = fit(_noisy(true, 0.01, 13), surface, model="auto")
    model = np.asarray(f.model)
    assert not np.any(model[sharp] == relight.MODELS.index("lambert"))
    pred = stage.simulate(f.maps(surface).frame(surface), rig, [cam], f.material(), lv, cv)
    peak = np.argmax(np.where(mask, t, -np.inf), 0)
    idx = (peak, np.arange(P))
    rel = np.abs(np.asarray(pred.radiance[0], np.float64).mean(-1)[idx] - t[idx]) / t[idx]
    assert np.mean(rel[sharp] < 0.1) >= 0.9, np.sort(rel[sharp])[::-1][:8]


@pytest.mark.parametrize("model", ["ggx", "blinn_phong"])
def test_a_lobe_the_lights_do_not_constrain_is_flagged_collapsed(scene, model):
    """Lambertian samples under a fixed lobed rung: the fit switches the lobe off (F0 to 0 or roughness to 1),
    where the sigmoid bounds flatten the Jacobian, so J^T J's sigma cannot say so. ``Fit.collapsed`` does, on
    nearly every such sample and on none of the glossy ones (F0 0.08-0.32); the report counts the same."""
    surface = scene[0]
    cap, lam = _half_lambertian(scene)
    f = fit(cap, surface, model=model)
    collapsed = np.asarray(f.collapsed)
    assert np.mean(collapsed[lam]) > 0.9
    assert not np.any(collapsed[~lam])
    assert relight.fitting.fit_report(f, surface)["collapsed_fraction"] == pytest.approx(np.mean(collapsed))


@pytest.mark.parametrize("solver", ["gn", "dogleg", "bfgs"])
def test_every_solver_is_safe(scene, solver):
    surface, rig, cam, lv, cv = scene
    rho, f0, alpha = _truth(surface.num_samples, seed=10)
    cap = _noisy(stage.simulate(surface, rig, [cam], brdf.lambert_ggx(rho, f0, alpha), lv, cv), 0.01, 11)
    f = fit(cap, surface, model="ggx", loss="cauchy", solver=solver, options=FitOptions(rounds=2))
    for leaf in jax.tree_util.tree_leaves(f):
        assert np.all(np.isfinite(np.asarray(leaf)))
    # Whatever the solver, a sample either succeeds or keeps a safe start: the
    # albedo (closed-form in the start) is never far off.
    assert np.median(np.abs(np.asarray(f.rho_d) - np.asarray(rho)) / np.asarray(rho)) < 0.05


def test_rig_roughness_floor():
    # Light Stage X: lights ~10.7 degrees apart -> a GGX lobe narrower than ~0.07 is not resolved.
    floor = relight.rig_alpha_floor(stage.light_stage_x())
    assert 0.05 < floor < 0.09
    dense = relight.rig_alpha_floor(stage.fibonacci_sphere(4000))
    assert dense == relight.ALPHA_FIT_MIN or dense < floor / 3


def test_sharp_lobe_is_reported_unresolved(scene):
    surface, rig, cam, lv, cv = scene
    rho, f0, _ = _truth(surface.num_samples, seed=12)
    alpha = jnp.full((surface.num_samples, 1), 0.02)  # mirror-like, far below the dome's ~17 degree spacing
    cap = stage.simulate(surface, rig, [cam], brdf.lambert_ggx(rho, f0 * 5, alpha), lv, cv)
    f = fit(cap, surface, model="ggx", loss="cauchy")
    assert f.alpha_floor > 0.1
    assert np.all(np.asarray(f.alpha) >= f.alpha_floor * 0.999)
    # Where a light falls near the mirror direction the lobe is seen and pinned at
    # the floor (flagged); where none does, the lobe is unobserved and its
    # roughness is whatever fits the diffuse lights (not flagged, but never below the floor).
    flagged = np.asarray(f.unresolved)
    assert np.mean(flagged) > 0.6
    assert np.all(np.asarray(f.alpha)[flagged, 0] < 1.25 * f.alpha_floor)


def test_uncertainty_matches_the_scatter_over_noise_draws(scene):
    surface, rig, cam, lv, cv = scene
    rho, f0, alpha = _truth(surface.num_samples, seed=13)
    clean = stage.simulate(surface, rig, [cam], brdf.lambert_ggx(rho, f0, alpha), lv, cv)
    draws = [fit(_noisy(clean, 0.02, 100 + k), surface, model="ggx", loss="l2") for k in range(6)]
    est = np.stack([np.asarray(d.rho_d) for d in draws])
    scatter = est.std(axis=0, ddof=1).mean()
    sigma = np.mean([np.asarray(d.uncertainty)[:, :3].mean() for d in draws])
    # J^T J's one-sigma agrees with the empirical spread of 6 draws to within the
    # sampling error of a 6-draw standard deviation (~30%) and model nonlinearity.
    assert 0.5 < sigma / scatter < 2.0


def _small(scene, seed):
    """The scene's capture of a fresh random material with 1% noise, and its surface. Every sample: the fit then
    has the shapes of the other tests' fits (one padded chunk, one observation count), so it reuses their
    compiled programs; the properties tested do not depend on the sample count."""
    surface, rig, cam, lv, cv = scene
    rho, f0, alpha = _truth(surface.num_samples, seed=seed)
    clean = stage.simulate(surface, rig, [cam], brdf.lambert_ggx(rho, f0, alpha), lv, cv)
    return _noisy(clean, 0.01, seed + 1), surface


def test_solver_object_is_the_named_solver(scene):
    """``solver="lm"`` is NormalLevenbergMarquardt(rtol=1e-5, atol=1e-6): that
    object gives the identical fit. ``"optx-lm"`` is optx.LevenbergMarquardt
    with the normal-equations Cholesky solver (that object: identical again);
    with Optimistix's default linear solver (QR) the same answer up to rounding
    (1e-6 relative: the two solve the same damped systems in float64). The two
    Levenberg-Marquardt implementations reach the same minimum."""
    cap, sub = _small(scene, seed=14)
    n = sub.num_samples
    calls = []
    ref = fit(cap, sub, model="ggx", loss="cauchy", options=FitOptions(progress=lambda *a: calls.append(a)))
    assert ref.solver == "lm"
    main = [c for c in calls if c[0] == "fit ggx"]  # the stragglers' later rounds: "fit ggx (more steps)"
    assert main[0] == ("fit ggx", 0, n) and main[-1] == ("fit ggx", n, n)
    assert all(b[1] >= a[1] for a, b in zip(main, main[1:], strict=False))
    same = fit(cap, sub, model="ggx", loss="cauchy",
               solver=relight.fitting.NormalLevenbergMarquardt(rtol=1e-5, atol=1e-6))
    assert same.solver == "NormalLevenbergMarquardt(rtol=1e-05, atol=1e-06)"
    for k in ("rho_d", "rho_s", "alpha", "normal", "steps", "result"):
        np.testing.assert_array_equal(np.asarray(getattr(same, k)), np.asarray(getattr(ref, k)))
    optx_lm = fit(cap, sub, model="ggx", loss="cauchy",
                  solver="optx-lm")
    same = fit(cap, sub, model="ggx", loss="cauchy",
               solver=optx.LevenbergMarquardt(rtol=1e-5, atol=1e-6,
                                              linear_solver=lx.Normal(relight.fitting.SPDCholesky())))
    qr = fit(cap, sub, model="ggx", loss="cauchy", solver=optx.LevenbergMarquardt(rtol=1e-5, atol=1e-6))
    assert qr.solver == "LevenbergMarquardt(rtol=1e-05, atol=1e-06)"
    for k in ("rho_d", "rho_s", "alpha", "normal", "steps", "result"):
        np.testing.assert_array_equal(np.asarray(getattr(same, k)), np.asarray(getattr(optx_lm, k)))
    for k in ("rho_d", "rho_s", "alpha"):
        np.testing.assert_allclose(np.asarray(getattr(qr, k)), np.asarray(getattr(optx_lm, k)), rtol=1e-6)
    # Both stop on the same tolerance from the same start at the same minimum:
    # they differ by well under the fit's own one-sigma uncertainty (measured
    # at most 0.24 sigma over the scene's 55 samples), and where they differ ours
    # is not worse (measured residual 8.5560e-4 vs 8.5570e-4 on the sample that
    # differs most).
    phys_ref = np.concatenate([np.asarray(ref.rho_d), np.asarray(ref.rho_s), np.asarray(ref.alpha)[:, :1]], axis=1)
    phys_optx = np.concatenate([np.asarray(optx_lm.rho_d), np.asarray(optx_lm.rho_s),
                                np.asarray(optx_lm.alpha)[:, :1]], axis=1)
    sigma = np.asarray(ref.uncertainty)[:, :5]
    assert np.all(np.abs(phys_ref - phys_optx) <= 0.5 * sigma + 1e-6)
    assert np.all(np.asarray(ref.residual) <= np.asarray(optx_lm.residual) * (1 + 1e-4))
    np.testing.assert_array_equal(np.asarray(qr.result), np.asarray(optx_lm.result))
    successful = relight.fitting.result_code(relight.fitting.RESULTS.successful)
    np.testing.assert_array_equal(np.asarray(ref.result), successful)


def test_bad_solver_or_progress_is_refused(scene):
    cap, sub = _small(scene, seed=16)
    with pytest.raises(ValueError, match="solver must be one of"):
        fit(cap, sub, model="ggx", loss="cauchy",
            solver="newton")
    with pytest.raises(TypeError, match="solver must be one of .* Optimistix solver object"):
        fit(cap, sub, model="ggx", loss="cauchy",
            solver=optx.Newton(rtol=1e-5, atol=1e-6))  # a root finder, not a least-squares solver
    with pytest.raises(TypeError, match="solver"):
        fit(cap, sub, model="ggx", loss="cauchy", solver=lambda u: u)
    with pytest.raises(ValueError, match="rtol / atol"):
        fit(cap, sub, model="ggx", loss="cauchy",
            solver=optx.LevenbergMarquardt(rtol=1e-5, atol=1e-6), options=FitOptions(rtol=1e-3))
    with pytest.raises(TypeError, match="progress"):
        fit(cap, sub, model="ggx", loss="cauchy", options=FitOptions(progress=3))
    with pytest.raises(TypeError, match="options"):
        fit(cap, sub, model="ggx", loss="cauchy", options=dict(chunk=8))


def test_a_sample_without_data_is_reported_unknown_not_certain(scene):
    """No valid observation: grey defaults, flagged failed, and every fitted
    parameter's uncertainty inf (unknown), not 0; the others stay finite."""
    cap, sub = _small(scene, seed=18)
    mask = np.array(cap.mask)
    mask[:, :, 0] = False
    f = fit(stage.Capture(cap.radiance, jnp.asarray(mask), cap.rig, cap.cameras), sub, model="ggx", loss="cauchy")
    unc = np.asarray(f.uncertainty)
    fitted = np.asarray(relight.fitting._ladder._union_index(relight.fitting._model.Layout(relight.MODELS.index("ggx"),
                                                                                          False, f.alpha_floor)))
    assert bool(np.asarray(f.failed)[0])
    assert np.all(np.isinf(unc[0, fitted])) and np.all(np.asarray(f.unidentified)[0, fitted])
    assert np.all(np.isfinite(unc[1:])) and not np.any(np.asarray(f.unidentified)[1:])
    assert np.all(unc[1:, fitted] > 0)
    for leaf in (f.rho_d, f.rho_s, f.alpha, f.normal, f.residual):
        assert np.all(np.isfinite(np.asarray(leaf)))

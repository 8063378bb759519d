"""relight.fitting.fit_patterns: the fit on pattern measurements against the OLAT fit (identity patterns),
recovery from 32 random patterns on the Light Stage X, what the four gradient patterns do and do not
determine, the pattern Jacobian against autodiff of the reference model, and bad or non-finite input."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdf
import relight
import stage
from relight.fitting import FitOptions, fit, fit_patterns
from relight.fitting import _model as _fit_model
from relight.fitting import _patterns as _fit_patterns
from relight.fitting._model import GGX, GGX_ANISO, LAMBERT, Layout

from ..scenes import uv_sphere

# Tight solver tolerances: noise-free recovery is then limited by float32 radiance, not the stopping rule.
TIGHT = dict(options=FitOptions(rtol=1e-9, atol=1e-10))


def _sphere(rig, every=4):
    mesh = uv_sphere(radius=50.0, n_lat=16, n_lon=32)
    surf = stage.texel_samples(mesh, 16)
    cam = stage.look_at((0.0, 0.0, 1000.0), fov_deg=10, width=64, height=64)
    lv = stage.light_visibility(mesh, surf, rig)
    cv = stage.camera_visibility(mesh, surf, [cam])
    # Samples facing the camera (cos_o > 0.3), so that every lobe is seen.
    p = np.asarray(surf.position)
    keep = np.nonzero(cv[0] & (p[:, 2] / 50.0 > 0.3))[0][::every]
    return surf.subset(keep), cam, lv[keep], cv[:, keep]


def _truth(P, seed=0, alpha_min=0.2):
    """Lambert + GGX parameters; ``alpha_min`` above the rig's roughness floor (relight.rig_alpha_floor:
    0.07 on the Light Stage X, 0.21 on the 42-light dome), where a lobe is resolved."""
    rng = np.random.default_rng(seed)
    return rng.uniform(0.1, 0.8, (P, 3)), rng.uniform(0.02, 0.08, (P, 1)), rng.uniform(alpha_min, 0.6, (P, 1))


def _ggx(rho, f0, alpha):
    return brdf.lambert_ggx(*(jnp.asarray(x, jnp.float32) for x in (rho, f0, alpha)))


def _rel(a, b):
    return float(np.max(np.abs(np.asarray(a, np.float64) - b) / np.abs(b)))


@pytest.fixture(scope="module")
def lsx():
    rig = stage.light_stage_x()
    surf, cam, lv, cv = _sphere(rig, every=2)  # 34 samples
    rho, f0, alpha = _truth(surf.num_samples)
    W = np.random.default_rng(7).uniform(0.0, 1.0, (32, rig.num_lights))
    pc = stage.simulate_patterns(surf, rig, [cam], _ggx(rho, f0, alpha), lv, cv, W)
    return dict(rig=rig, surf=surf, cam=cam, lv=lv, cv=cv, rho=rho, f0=f0, alpha=alpha, W=W, pc=pc)


def test_identity_patterns_match_the_olat_fit():
    # One pattern per light is the OLAT capture itself: the same least squares, so the same answer.
    rig = stage.geodesic_dome(1)  # 42 distant lights
    surf, cam, lv, cv = _sphere(rig)
    rho, f0, alpha = _truth(surf.num_samples, seed=1, alpha_min=0.3)
    cap = stage.simulate(surf, rig, [cam], _ggx(rho, f0, alpha), lv, cv)
    olat = fit(cap, surf, loss="l2", **TIGHT)
    pat = fit_patterns(stage.capture_patterns(cap, np.eye(rig.num_lights)), surf, lv, **TIGHT)
    assert isinstance(pat, relight.Fit) and not np.any(np.asarray(pat.failed))
    for k in ("rho_d", "rho_s", "alpha", "normal"):
        # Both converge to the truth to float32 rounding (~1e-6): they agree to 1e-5.
        np.testing.assert_allclose(np.asarray(getattr(pat, k)), np.asarray(getattr(olat, k)), rtol=1e-5, atol=1e-7)
    assert _rel(pat.rho_d, rho) < 1e-4 and _rel(pat.alpha[:, :1], alpha) < 1e-4
    # Pattern measurements are (view, pattern) pairs: every light is one here, lit or not.
    np.testing.assert_array_equal(np.asarray(pat.observed), rig.num_lights)
    # The same sum of squares: the OLAT RMS runs over its lit observations, the pattern RMS over all 42. Both
    # fits reach the noise-free truth, so what is left is each residual's float32 rounding, up to eps * max
    # radiance per observation: which rounding depends on the code XLA emits (tests.helpers.TEST_XLA_FLAGS),
    # so the sums agree to that floor, 42 observations of (eps * max)^2 (4e-14 here; measured up to 2.1e-15).
    sse_olat = np.asarray(olat.residual, np.float64) ** 2 * np.asarray(olat.observed)
    sse_pat = np.asarray(pat.residual, np.float64) ** 2 * rig.num_lights
    floor = rig.num_lights * (float(np.finfo(np.float32).eps) * float(np.max(np.asarray(cap.radiance)))) ** 2
    np.testing.assert_allclose(sse_pat, sse_olat, rtol=1e-3, atol=floor)


def test_32_random_patterns_recover_ggx_on_the_light_stage_x(lsx):
    P = lsx["surf"].num_samples
    rng = np.random.default_rng(3)
    start = dict(rho_d=np.clip(lsx["rho"] * rng.uniform(0.8, 1.2, (P, 3)), 0.0, 1.0),
                 rho_s=lsx["f0"][:, 0] * rng.uniform(0.7, 1.3, P), alpha=lsx["alpha"][:, 0] * rng.uniform(0.8, 1.2, P))
    holes = {k: v.copy() for k, v in start.items()}
    holes["rho_d"][0, 1] = np.nan  # a decoder's NaN: that sample gets the default start
    holes["alpha"][5] = np.inf
    # A perturbed start (a decoder's, say), one with holes, and the default start from the measurements.
    for st in (start, holes, None):
        f = fit_patterns(lsx["pc"], lsx["surf"], lsx["lv"], start=st, **TIGHT)
        assert not np.any(np.asarray(f.failed))
        # 32 measurements x 3 channels for 5 unknowns, noise-free: exact up to float32 radiance (measured on
        # 17 samples: rho_d 3e-6, rho_s 8e-5, alpha 3e-5).
        assert _rel(f.rho_d, lsx["rho"]) < 1e-3
        assert _rel(f.rho_s, lsx["f0"]) < 1e-3
        assert _rel(f.alpha[:, :1], lsx["alpha"]) < 1e-3
        np.testing.assert_array_equal(np.asarray(f.observed), 32)
        maps = f.maps(lsx["surf"])
        np.testing.assert_allclose(np.asarray(maps.rho_d), np.asarray(f.rho_d))


def test_gradient_patterns_recover_lambert_albedo_and_normal(lsx):
    rig, surf = lsx["rig"], lsx["surf"]
    G = stage.gradient_patterns(rig)
    pc = stage.simulate_patterns(surf, rig, [lsx["cam"]], brdf.Lambert(jnp.asarray(lsx["rho"], jnp.float32)),
                                 lsx["lv"], lsx["cv"], G)
    n_true = np.asarray(surf.normal, np.float64)
    for normals in (False, True):
        f = fit_patterns(pc, surf, lsx["lv"], model="lambert", normals=normals, **TIGHT)
        assert not np.any(np.asarray(f.failed))
        np.testing.assert_array_equal(np.asarray(f.observed), 4)
        assert _rel(f.rho_d, lsx["rho"]) < 1e-4
        n = np.asarray(f.normal, np.float64)
        err = np.degrees(np.arccos(np.clip(np.sum(n * n_true, 1) / np.linalg.norm(n, axis=1), -1, 1)))
        assert err.max() < 0.05, err.max()  # float32 normals and radiance
        assert np.all(np.isfinite(np.asarray(f.uncertainty)[:, :3]))
    # The default start's normal alone (Ma et al.'s linear solve, module docstring): a few degrees on the
    # near-field rig, where the gradients are those of the rig centre, not of each sample.
    lay = Layout(LAMBERT, True, 0.05)
    L = rig.num_lights
    arrays, *_ = _fit_patterns._block_arrays(pc, lsx["lv"], surf, np.asarray(G, np.float64), np.ones(L, bool), 0,
                                             surf.num_samples, L, np.float64)
    p0 = jax.jit(jax.vmap(lambda *a: _fit_patterns.pattern_start(*a, lay)))(*(jnp.asarray(x) for x in arrays))
    tilt = np.degrees(np.arccos(np.clip(np.asarray(p0["normal"])[:, 2], -1, 1)))
    assert np.median(tilt) < 5.0, tilt


def test_gradient_patterns_leave_the_roughness_unidentified(lsx, key):
    """The four gradient patterns give per channel a lobe's zeroth and first moments only (Ma et al. 2007):
    the GGX rung's diffuse / specular split and its roughness are then loose, and the fit says so; 32 random
    patterns pin them down."""
    rig, surf, lv = lsx["rig"], lsx["surf"], lsx["lv"]
    G = stage.gradient_patterns(rig)
    sim = lambda mat, W: stage.simulate_patterns(surf, rig, [lsx["cam"]], mat, lv, lsx["cv"], W)  # noqa: E731
    # 1. Noise-free Lambertian truth, the GGX rung: a broad grey lobe trades places with the albedo at zero
    # residual, so the albedo is not recovered and the roughness is reported unidentified (sigma inf: its
    # Jacobian column is null at the fitted point). Measured (34 samples): rho_d off by up to 29% (fitted
    # rho_s up to 0.12), alpha unidentified on 30 of 34 samples. (32 random patterns of the same truth: rho_d
    # within 3.9%, the rest of a lobe that the default tolerances stop short of driving to rho_s = 0.)
    lam = brdf.Lambert(jnp.asarray(lsx["rho"], jnp.float32))
    f = fit_patterns(sim(lam, G), surf, lv)
    assert _rel(f.rho_d, lsx["rho"]) > 0.1
    assert np.mean(np.asarray(f.unidentified)[:, 4]) > 0.5
    # 2. GGX truth under shot noise (one exposure for both: the brightest gradient measurement collects 2e4
    # photo-electrons): the roughness' relative 1-sigma from J^T J. Measured over 3 seeds: median 1.1-5.3
    # with the gradients, 0.13-0.18 with 32 random patterns.
    mat = _ggx(lsx["rho"], lsx["f0"], lsx["alpha"])
    pg = sim(mat, G)
    sensor = stage.Sensor(exposure=2e4 / float(np.max(np.asarray(pg.radiance))), shot_noise=True)
    rel = {}
    for name, pc in (("gradient", pg), ("random32", lsx["pc"])):
        f = fit_patterns(stage.sense_patterns(pc, sensor, key), surf, lv)
        for leaf in (f.rho_d, f.rho_s, f.alpha, f.residual):
            assert np.all(np.isfinite(np.asarray(leaf)))
        rel[name] = float(np.median(np.asarray(f.uncertainty)[:, 4] / np.asarray(f.alpha[:, 0])))  # inf: unknown
    assert rel["gradient"] > 0.75 and rel["random32"] < 0.3 and rel["gradient"] > 4 * rel["random32"], rel


@pytest.mark.parametrize("model, normals, c", [(GGX, False, None), (GGX_ANISO, True, 0.02), (LAMBERT, True, None)])
def test_pattern_jacobian_matches_autodiff_of_the_reference_model(model, normals, c):
    """J_pattern = W_eff J_olat (then the robust scaling) against jax.jacfwd of the pattern prediction built
    from _model.predict (the brdf-composed stage forward model), float64, two views; and finite where
    lights graze the horizon."""
    rng = np.random.default_rng(11)
    V, K, Lk = 2, 5, 24
    lay = Layout(model, normals, 0.05)
    wi = rng.normal(size=(Lk, 3)) * [1.0, 1.0, 0.6] + [0.0, 0.0, 0.4]
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wi[0] = [1.0, 0.0, 0.0]  # exactly at the horizon
    wo = np.asarray([[0.2, -0.1, 0.97], [-0.6, 0.3, 0.74]])
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    irr = rng.uniform(0.5, 1.5, (Lk, 3))
    weff = rng.uniform(0.0, 1.0, (K, Lk)) * (rng.uniform(size=Lk) > 0.2)
    obs = rng.uniform(0.0, 2.0, (V, K, 3))
    sw = np.sqrt((rng.uniform(size=(V, K, 3)) > 0.1).astype(np.float64))
    u = jnp.asarray(rng.normal(size=lay.size) * 0.4)
    j = jnp.asarray
    r, J, pat = jax.jit(lambda v: _fit_patterns._pattern_residual(v, j(obs), j(sw), j(weff), j(wi), j(wo), j(irr),
                                                                    lay, c))(u)

    def reference(v):
        p = _fit_model.unpack(v, lay)
        per_view = [_fit_model.predict(p, lay, j(wi), jnp.broadcast_to(j(wo[i]), (Lk, 3)), j(irr)) for i in range(V)]
        pred = jnp.einsum("kl,vlc->vkc", j(weff), jnp.stack(per_view))
        return _fit_model.robust(j(sw) * (pred - j(obs)), c).reshape(-1), pred

    # One compiled program for the reference and its Jacobian (op-by-op dispatch compiles every primitive).
    r_ref, pat_ref, J_ref = jax.jit(lambda v: (*reference(v), jax.jacfwd(lambda x: reference(x)[0])(v)))(u)
    assert np.all(np.isfinite(np.asarray(J))) and np.all(np.isfinite(np.asarray(r)))
    np.testing.assert_allclose(np.asarray(pat), np.asarray(pat_ref), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(np.asarray(r), np.asarray(r_ref), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(np.asarray(J), np.asarray(J_ref), atol=1e-9 * float(jnp.max(jnp.abs(J_ref))))


def test_non_finite_measurements_are_flagged_not_propagated(lsx):
    pc = lsx["pc"]
    rad = np.array(pc.radiance)
    rad[0, 3, 0, 1] = np.nan  # sample 0: one channel of one pattern
    rad[0, :, 1] = np.nan  # sample 1: every measurement
    rad[0, 5, 2, :] = np.inf  # sample 2: one pattern
    bad = stage.PatternCapture(jnp.asarray(rad), pc.valid, pc.patterns, pc.rig, pc.cameras)
    f = fit_patterns(bad, lsx["surf"], stage.PackedMask.pack(lsx["lv"]), **TIGHT)  # the packed form too
    for leaf in (f.rho_d, f.rho_s, f.alpha, f.normal, f.residual, f.uncertainty[:, :3]):
        assert not np.any(np.isnan(np.asarray(leaf)))
    for leaf in (f.rho_d, f.rho_s, f.alpha, f.normal, f.residual):
        assert np.all(np.isfinite(np.asarray(leaf)))
    obs = np.asarray(f.observed)
    assert obs[0] == 31 and obs[1] == 0 and obs[2] == 31 and np.all(obs[3:] == 32)
    failed = np.asarray(f.failed)
    assert failed[1] and not failed[0] and not failed[2] and not failed[3:].any()
    assert np.all(np.isinf(np.asarray(f.uncertainty)[1, :5]))
    # The samples that lost a measurement still have 31 x 3 exact ones for 5 unknowns.
    ok = np.r_[0, 2:lsx["surf"].num_samples]
    assert _rel(np.asarray(f.rho_d)[ok], lsx["rho"][ok]) < 1e-3
    assert _rel(np.asarray(f.alpha)[ok, :1], lsx["alpha"][ok]) < 1e-3


def test_bad_arguments_are_refused_naming_them(lsx):
    pc, surf, lv = lsx["pc"], lsx["surf"], lsx["lv"]
    P = surf.num_samples
    with pytest.raises(ValueError, match="light_visibility"):
        fit_patterns(pc, surf, lv[:, :10])
    with pytest.raises(ValueError, match="model"):
        fit_patterns(pc, surf, lv, model="auto")
    with pytest.raises(ValueError, match="samples"):
        fit_patterns(pc, surf.subset(np.arange(3)), lv)
    with pytest.raises(ValueError, match="start"):
        fit_patterns(pc, surf, lv, start=dict(rho_d=np.full((P, 3), 0.5), rho_s=np.full(P, 0.04)))
    with pytest.raises(ValueError, match="start"):
        fit_patterns(pc, surf, lv, start=dict(rho_d=np.full((P, 2), 0.5), rho_s=np.full(P, 0.04),
                                              alpha=np.full(P, 0.3)))
    with pytest.raises(ValueError, match="start"):
        fit_patterns(pc, surf, lv, start=dict(rho_d=np.full((P, 3), 1.5), rho_s=np.full(P, 0.04),
                                              alpha=np.full(P, 0.3)))
    with pytest.raises(ValueError, match="loss"):
        fit_patterns(pc, surf, lv, loss="huber")
    with pytest.raises(TypeError, match="PatternCapture"):
        fit_patterns(np.zeros(3), surf, lv)


def test_two_views_and_progress():
    # Two cameras 40 degrees apart: each sample's measurements from both views enter one solve.
    rig = stage.geodesic_dome(1)
    mesh = uv_sphere(radius=50.0, n_lat=16, n_lon=32)
    surf = stage.texel_samples(mesh, 16)
    cams = [stage.look_at((0.0, 0.0, 1000.0), fov_deg=10, width=64, height=64),
            stage.look_at((643.0, 0.0, 766.0), fov_deg=10, width=64, height=64)]
    lv = stage.light_visibility(mesh, surf, rig)
    cv = stage.camera_visibility(mesh, surf, cams)
    # Views at least 6 degrees above each sample's horizon: the fitter keeps cos_o >= 0.02
    # (_model.view_above_horizon), so a view grazing more than that is not modelled exactly.
    cos_o = np.stack([np.asarray(surf.to_local(c.view_directions(surf.position)))[:, 2] for c in cams])
    keep = np.nonzero((cv[0] | cv[1]) & np.all(~cv | (cos_o > 0.1), axis=0))[0][::5]
    surf, lv, cv = surf.subset(keep), lv[keep], cv[:, keep]
    rho, f0, alpha = _truth(surf.num_samples, seed=4, alpha_min=0.3)
    W = np.random.default_rng(5).uniform(0.0, 1.0, (12, rig.num_lights))
    pc = stage.simulate_patterns(surf, rig, cams, _ggx(rho, f0, alpha), lv, cv, W)
    calls = []
    progress = lambda phase, done, total: calls.append((phase, done, total))  # noqa: E731
    f = fit_patterns(pc, surf, lv, options=FitOptions(progress=progress, rtol=1e-9, atol=1e-10))
    both = np.asarray(pc.valid).all(axis=0)
    assert both.sum() >= 5 and (~both).sum() >= 5
    np.testing.assert_array_equal(np.asarray(f.observed), np.where(both, 24, 12))
    # Samples seen twice have 24 x 3 exact measurements, seen once 12 x 3: enough for 5 unknowns either way.
    assert _rel(f.rho_d, rho) < 1e-3
    assert _rel(f.alpha[:, :1], alpha) < 1e-3
    main = [c for c in calls if c[0] == "fit ggx"]  # stragglers' later rounds: "fit ggx (more steps)", no total
    assert {c[0] for c in calls} <= {"fit ggx", "fit ggx (more steps)"}
    assert main and main[-1][1:] == (surf.num_samples, surf.num_samples)

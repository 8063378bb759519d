"""Radiometric scale invariance of relight.fit (docs/fit.md, "Units and scale").

The fitter normalises each sample's observations and irradiance by one
per-sample irradiance scale, so the solver's tolerances, the Cauchy scale,
the start's floors and the accept test never see the capture's absolute
units: the same scene in other units (rig intensities x k and radiance x k)
gives the same maps, a rig whose intensity is 1 (irradiance ~1/d^2 ~ 6e-7
at 1.3 m) fits like one normalised to 1 at the centre, and a darker
exposure of a Lambertian scene (radiance x k, rig unchanged) gives albedos
x k with the same normals."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdf
import relight
import stage

from ..scenes import uv_sphere

# The roughness floor of every fit below but the float32 and Lambert ones (those keep the rig's own): the floor of
# tests/relight/test_fit.py's rig. The floor is a compiled constant of the solver, so with it, and the scene's
# shapes, these fits run test_fit.py's programs. It depends on the light directions only, never on the units, so
# any fixed floor tests the same invariance (the truth's roughness, 0.15-0.6, is above it either way).
FLOOR = relight.rig_alpha_floor(stage.geodesic_dome(2))


@pytest.fixture(scope="module")
def scene():
    """82 camera-facing texels of a 50 mm sphere at the centre of the Light
    Stage X's 201 unpolarised lights, intensity 1 per light (irradiance ~6e-7).
    Each texel sees 40-95 of the lights: the fit packs 96 observations per
    texel in chunks of 64, the shapes of tests/relight/test_fit.py's fits, so
    with its roughness floor (FLOOR) the GGX, GGX + normals and ladder fits here
    run the solver programs those compile (tests/conftest.py's cache); the
    properties tested do not depend on the rig's light count."""
    mesh = uv_sphere(radius=50.0, n_lat=16, n_lon=32)
    surface = stage.texel_samples(mesh, 24)
    lsx = stage.light_stage_x("unpolarized")
    rig = stage.make_rig(np.asarray(lsx.position), intensity=1.0)
    cam = stage.look_at((0.0, 0.0, 1000.0), fov_deg=10, width=256, height=256)
    lv = stage.light_visibility(mesh, surface, rig)
    cv = stage.camera_visibility(mesh, surface, [cam])
    p = np.asarray(surface.position)
    keep = np.nonzero(cv[0] & (p[:, 2] / 50.0 > 0.3))[0][::2]
    return surface.subset(keep), rig, cam, lv[keep], cv[:, keep]


def _truth(n, seed):
    rng = np.random.default_rng(seed)
    rho = rng.uniform(0.1, 0.8, (n, 3))
    f0 = rng.uniform(0.02, 0.08, (n, 1))
    alpha = rng.uniform(0.15, 0.6, (n, 1))
    return (jnp.asarray(x, jnp.float32) for x in (rho, f0, alpha))


def _scaled(cap, k, rig=None):
    """The capture with radiance x k (and, if given, another rig)."""
    rad = jnp.asarray(np.asarray(cap.radiance, np.float64) * k, cap.radiance.dtype)
    return stage.Capture(rad, cap.mask, cap.rig if rig is None else rig, cap.cameras)


def _rig_times(rig, k):
    return stage.Rig(rig.position, jnp.asarray(np.asarray(rig.intensity, np.float64) * k, rig.intensity.dtype),
                     rig.solid_angle, rig.near_field)


def _noisy(cap, sigma, seed):
    eps = 1 + sigma * np.random.default_rng(seed).standard_normal(cap.radiance.shape)
    return stage.Capture(cap.radiance * jnp.asarray(eps, cap.radiance.dtype), cap.mask, cap.rig, cap.cameras)


def test_intensity_one_rig_recovers_albedo(scene):
    """201 lights of intensity 1 (radiance ~1e-7): before the normalisation the
    solver's absolute atol stopped LM after one step (93% albedo error)."""
    surface, rig, cam, lv, cv = scene
    rho, f0, alpha = _truth(surface.num_samples, seed=0)
    cap = _noisy(stage.simulate(surface, rig, [cam], brdf.lambert_ggx(rho, f0, alpha), lv, cv), 0.01, 1)
    assert float(np.max(np.asarray(cap.radiance))) < 1e-5
    f = relight.fit(cap, surface, model="ggx", loss="cauchy", alpha_floor=FLOOR)
    err = np.abs(np.asarray(f.rho_d) - np.asarray(rho)) / np.asarray(rho)
    assert np.median(err) < 0.01
    assert np.median(np.asarray(f.steps)) > 3
    assert np.mean(np.asarray(f.failed)) < 0.1
    # Fit.residual is in the capture's radiance units: about 1% of the radiance.
    rms = np.sqrt(np.sum(np.asarray(cap.radiance, np.float64) ** 2 * np.asarray(cap.mask)[..., None], (0, 1, 3))
                  / (3 * np.maximum(np.sum(np.asarray(cap.mask), (0, 1)), 1)))
    ratio = np.asarray(f.residual) / rms
    assert 0.003 < np.median(ratio) < 0.03


@pytest.fixture(scope="module")
def units_ref(scene):
    """test_other_units_give_the_same_maps' capture (GGX, 1% noise) and its fit in the rig's own units (GGX +
    normals), made once for both scales k."""
    surface, rig, cam, lv, cv = scene
    rho, f0, alpha = _truth(surface.num_samples, seed=2)
    cap = _noisy(stage.simulate(surface, rig, [cam], brdf.lambert_ggx(rho, f0, alpha), lv, cv), 0.01, 3)
    return cap, relight.fit(cap, surface, model="ggx", loss="cauchy", normals=True, alpha_floor=FLOOR)


@pytest.mark.parametrize("k", [1e-6, 1e6])
def test_other_units_give_the_same_maps(scene, units_ref, k):
    """The same physical scene in other units: rig intensities x k and radiance
    x k. 1% noise (the same draw), GGX + normals: the normalised problems
    differ only by the float32 rounding of the scaled radiance and rig
    intensities (~1e-7), and the solver stops anywhere within its rtol
    (1e-5), so the maps agree to 1e-4 relative (measured: 5e-6) and the
    failed flags and result codes are identical; Fit.residual scales with k
    (capture units); the uncertainties do not (parameter units)."""
    surface, rig = scene[:2]
    cap, ref = units_ref
    other = relight.fit(_scaled(cap, k, _rig_times(rig, k)), surface, model="ggx", loss="cauchy",
                                                   normals=True, alpha_floor=FLOOR)
    for name in ("rho_d", "rho_s", "alpha", "normal", "uncertainty"):
        np.testing.assert_allclose(np.asarray(getattr(other, name)), np.asarray(getattr(ref, name)),
                                   rtol=1e-4, atol=1e-7, err_msg=name)
    for name in ("failed", "result"):
        np.testing.assert_array_equal(np.asarray(getattr(other, name)), np.asarray(getattr(ref, name)), err_msg=name)
    assert np.mean(np.asarray(other.steps) == np.asarray(ref.steps)) > 0.9
    np.testing.assert_allclose(np.asarray(other.residual), k * np.asarray(ref.residual), rtol=1e-4)


@pytest.fixture(scope="module")
def ladder_ref(scene):
    """test_ladder_and_heldout_are_unit_free's capture (GGX, 1% noise) and its model="auto" fit in the rig's own
    units, made once for both scales k. Every sample of the scene: the GGX rung's program is then
    test_intensity_one_rig_recovers_albedo's (one padded chunk shape), compiled once."""
    surface, rig, cam, lv, cv = scene
    rho, f0, alpha = _truth(surface.num_samples, seed=4)
    cap = _noisy(stage.simulate(surface, rig, [cam], brdf.lambert_ggx(rho, f0, alpha), lv, cv), 0.01, 5)
    return cap, relight.fit(cap, surface, model="auto", alpha_floor=FLOOR, options=relight.fitting.FitOptions(rounds=1))


@pytest.mark.parametrize("k", [1e-6, 1e6])
def test_ladder_and_heldout_are_unit_free(scene, ladder_ref, k):
    """model="auto": the same rung per sample in any units; the held-out RMS in capture units."""
    surface, rig = scene[:2]
    cap, ref = ladder_ref
    other = relight.fit(_scaled(cap, k, _rig_times(rig, k)), surface, model="auto", alpha_floor=FLOOR,
                        options=relight.fitting.FitOptions(rounds=1))
    np.testing.assert_array_equal(np.asarray(other.model), np.asarray(ref.model))
    # Tolerances as in test_other_units_give_the_same_maps (float32 inputs, solver rtol 1e-5).
    np.testing.assert_allclose(np.asarray(other.rho_d), np.asarray(ref.rho_d), rtol=1e-4)
    np.testing.assert_allclose(np.asarray(other.heldout), k * np.asarray(ref.heldout), rtol=1e-4)


def test_darker_exposure_scales_the_albedo(scene):
    """Radiance x k with the rig unchanged is a k-times darker material: a
    Lambertian scene's albedos scale by k (noise-free: to 1e-4 relative) and
    its normals stay, with nothing flagged, for k = 0.1 and 1e-2. (For a
    specular rung radiance x k is not a material of the model -- Schlick's
    c^5 term does not scale with F0 -- and k > 1 can exceed albedo 1.)"""
    surface, rig, cam, lv, cv = scene
    rho, _, _ = _truth(surface.num_samples, seed=6)
    cap = stage.simulate(surface, rig, [cam], brdf.Lambert(rho), lv, cv)
    ref = relight.fit(cap, surface, model="lambert", normals=True)
    np.testing.assert_allclose(np.asarray(ref.rho_d), np.asarray(rho), rtol=1e-4)
    for k in (0.1, 1e-2):
        f = relight.fit(_scaled(cap, k), surface, model="lambert", normals=True)
        assert not np.any(np.asarray(f.failed))
        np.testing.assert_allclose(np.asarray(f.rho_d), k * np.asarray(ref.rho_d), rtol=1e-4)
        np.testing.assert_allclose(np.asarray(f.normal), np.asarray(ref.normal), atol=1e-5)


def test_other_units_in_float32(scene):
    """As test_other_units_give_the_same_maps in the fitter's default float32
    (x64 off): the same failed flags (the accept test's slack covers float32
    rounding of the cost, which alone flagged 1-2% of samples before), and
    maps equal to float32 solver noise: median relative difference < 1e-4
    (measured 1e-7 .. 1e-5), every sample within 5% (measured worst: 1.6% on
    the rho_s of one weak lobe; rho_d 7e-4, alpha 4e-3, normals 2e-4)."""
    surface, rig, cam, lv, cv = scene
    rho, f0, alpha = _truth(surface.num_samples, seed=7)
    cap = _noisy(stage.simulate(surface, rig, [cam], brdf.lambert_ggx(rho, f0, alpha), lv, cv), 0.01, 8)
    k = 1e6
    with jax.enable_x64(False):
        ref = relight.fit(cap, surface, model="ggx", loss="cauchy", normals=True)
        other = relight.fit(_scaled(cap, k, _rig_times(rig, k)), surface, model="ggx", loss="cauchy", normals=True)
    assert ref.rho_d.dtype == jnp.float32
    np.testing.assert_array_equal(np.asarray(other.failed), np.asarray(ref.failed))
    assert np.mean(np.asarray(ref.failed)) < 0.05
    for name in ("rho_d", "rho_s", "alpha", "normal"):
        a, b = np.asarray(getattr(other, name), np.float64), np.asarray(getattr(ref, name), np.float64)
        rel = np.abs(a - b) / (np.abs(b) + 1e-3)
        assert np.median(rel) < 1e-4 and np.max(rel) < 0.05, (name, np.median(rel), np.max(rel))

import jax.numpy as jnp
import numpy as np
import pytest

import brdf
import stage
from relight import fit

from ..stage.geometry import uv_sphere


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
    f = fit(cap, surface)
    assert not np.any(np.asarray(f.failed))
    # The model is the simulator's: recovery is limited by float32 and the solver tolerance.
    np.testing.assert_allclose(np.asarray(f.rho_d), np.asarray(rho), rtol=2e-3)
    np.testing.assert_allclose(np.asarray(f.alpha), np.asarray(alpha), rtol=1e-2)
    np.testing.assert_allclose(np.asarray(f.f0), np.asarray(f0), rtol=2e-2)
    assert float(np.max(np.asarray(f.residual))) < 1e-4


def test_one_percent_noise(scene):
    surface, rig, cam, lv, cv = scene
    rho, f0, alpha = _truth(surface.num_samples, seed=1)
    cap = stage.simulate(surface, rig, [cam], brdf.lambert_ggx(rho, f0, alpha), lv, cv)
    noise = 1 + 0.01 * np.random.default_rng(2).standard_normal(cap.radiance.shape)
    cap = stage.Capture(cap.radiance * jnp.asarray(noise, jnp.float32), cap.mask, cap.rig, cap.cameras)
    f = fit(cap, surface)
    err_rho = np.abs(np.asarray(f.rho_d) - np.asarray(rho)) / np.asarray(rho)
    err_alpha = np.abs(np.asarray(f.alpha) - np.asarray(alpha)) / np.asarray(alpha)
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
    f = fit(cap, surface)
    for leaf in (f.rho_d, f.f0, f.alpha, f.residual):
        assert np.all(np.isfinite(np.asarray(leaf)))
    assert bool(f.failed[0])
    assert float(np.max(np.asarray(f.rho_d)[1])) < 0.01


def test_mismatched_capture_is_refused(scene):
    surface, rig, cam, lv, cv = scene
    rho, f0, alpha = _truth(surface.num_samples)
    cap = stage.simulate(surface, rig, [cam], brdf.lambert_ggx(rho, f0, alpha), lv, cv)
    with pytest.raises(ValueError, match="samples"):
        fit(cap, surface.subset(np.arange(3)))

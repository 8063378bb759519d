"""Fit.ambiguous: at low photon counts noise lets a broad grey lobe take part
of the diffuse signal (at an equal or lower cost than the truth: issue 17's
dark speckles on a 162-light dome); the fit's own albedo uncertainty flags
every such sample."""

import jax.numpy as jnp
import numpy as np

import brdf
import relight
import stage

from ..scenes import uv_sphere


def _front_of_sphere(texels: int, pixels: int):
    """The texels of a sphere (radius 50) facing a distant camera, under a geodesic dome: (surface, rig,
    camera, light visibility, camera visibility)."""
    mesh = uv_sphere(radius=50.0, n_lat=24, n_lon=48)
    surface = stage.texel_samples(mesh, texels)
    rig = stage.geodesic_dome(2)
    cam = stage.look_at((0.0, 0.0, 1000.0), fov_deg=10, width=pixels, height=pixels)
    lv = stage.light_visibility(mesh, surface, rig)
    cv = stage.camera_visibility(mesh, surface, [cam])
    keep = np.nonzero(cv[0] & (np.asarray(surface.position)[:, 2] / 50.0 > 0.3))[0]
    return surface.subset(keep), rig, cam, lv[keep], cv[:, keep]


def test_albedo_traded_for_a_lobe_is_flagged_ambiguous():
    surface, rig, cam, lv, cv = _front_of_sphere(32, 256)
    n = surface.num_samples
    rng = np.random.default_rng(0)
    # Skin-like: a faint broad lobe over a reddish diffuse term.
    rho = jnp.asarray(np.clip(np.array([0.6, 0.4, 0.3]) * rng.uniform(0.7, 1.3, (n, 1)), 0, 1), jnp.float32)
    truth = brdf.lambert_ggx(rho, jnp.full((n, 1), 0.028, jnp.float32), jnp.full((n, 1), 0.37, jnp.float32))
    cap = stage.simulate(surface, rig, [cam], truth, lv, cv)
    x = np.asarray(cap.radiance)
    peak = np.percentile(x[np.asarray(cap.mask)], 99.9)
    photons = 100  # at the brightest observation: shot noise 10% there, more in the dark
    noisy = rng.poisson(x / peak * photons) / photons * peak
    f = relight.fit(stage.Capture(jnp.asarray(noisy, jnp.float32), cap.mask, cap.rig, cap.cameras), surface,
                    model="ggx", loss="cauchy")
    ratio = np.asarray(f.rho_d) / np.asarray(rho)
    dark = np.any(ratio < 0.8, axis=1)
    amb = np.asarray(f.ambiguous)
    # Measured: 8 of 280 samples below 0.8x (down to 0.56x), all 8 flagged;
    # 23 flagged in all (8%).
    assert dark.sum() >= 3
    assert np.all(amb[dark])
    assert amb.mean() < 0.15
    # The flag is the albedo's relative 1-sigma: unflagged samples are within a few sigma of the truth.
    ok = ~amb
    z = np.abs(np.asarray(f.rho_d) - np.asarray(rho))[ok] / np.asarray(f.uncertainty)[ok, :3]
    assert np.median(z) < 1.5


def test_a_switched_off_lobe_is_held_for_the_albedos_sigma():
    # Lambertian data under the GGX rung: where the fit switches the lobe off (F0 below Fit.COLLAPSED_F0)
    # the lobe is held at its bound for the covariance, as bounded least squares holds a parameter at an
    # active bound: the albedo's 1-sigma is then the Lambert rung's on the same data (same residuals, same
    # free parameters), and the lobe's own sigmas are unknown, not small.
    surface, rig, cam, lv, cv = _front_of_sphere(24, 128)
    n = surface.num_samples
    rng = np.random.default_rng(1)
    rho = jnp.asarray(rng.uniform(0.2, 0.7, (n, 3)), jnp.float32)
    cap = stage.simulate(surface, rig, [cam], brdf.Lambert(rho), lv, cv)
    x = np.asarray(cap.radiance)
    noisy = x + 0.01 * np.percentile(x[np.asarray(cap.mask)], 99) * rng.normal(size=x.shape)
    noisy_cap = stage.Capture(jnp.asarray(np.maximum(noisy, 0.0), jnp.float32), cap.mask, cap.rig, cap.cameras)
    lam = relight.fit(noisy_cap, surface, model="lambert")
    ggx = relight.fit(noisy_cap, surface, model="ggx")
    off = np.asarray(ggx.rho_s)[:, 0] < relight.Fit.COLLAPSED_F0
    assert off.sum() >= 10  # measured: most samples
    ratio = np.asarray(ggx.uncertainty)[off, :3] / np.asarray(lam.uncertainty)[off, :3]
    # The same covariance factor (J^T J of the albedo alone) scaled by each fit's own residual: the ratio of
    # the sigmas is the ratio of the residual RMS (measured: 1 to 1e-6; before the hold, up to 8.9x at the
    # 99th percentile, the lobe's flat sigmoid columns leaking into the albedo's).
    rms_ratio = (np.asarray(ggx.residual) / np.asarray(lam.residual))[off, None]
    np.testing.assert_allclose(ratio / rms_ratio, 1.0, atol=1e-3)
    assert np.all(np.isinf(np.asarray(ggx.uncertainty)[off, 3:5]))  # F0 and alpha
    assert not np.any(np.asarray(ggx.ambiguous)[off])

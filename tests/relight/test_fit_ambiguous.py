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


def test_albedo_traded_for_a_lobe_is_flagged_ambiguous():
    mesh = uv_sphere(radius=50.0, n_lat=24, n_lon=48)
    surface = stage.texel_samples(mesh, 32)
    rig = stage.geodesic_dome(2)
    cam = stage.look_at((0.0, 0.0, 1000.0), fov_deg=10, width=256, height=256)
    lv = stage.light_visibility(mesh, surface, rig)
    cv = stage.camera_visibility(mesh, surface, [cam])
    keep = np.nonzero(cv[0] & (np.asarray(surface.position)[:, 2] / 50.0 > 0.3))[0]
    surface, lv, cv = surface.subset(keep), lv[keep], cv[:, keep]
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

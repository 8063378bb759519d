"""A highlight the lights never saw (relight.fitting._extrapolation): a lobe whose peak lies between the
lights and predicts more than any observation is flagged (closed-form cases; that ``model="auto"`` steps
such a sample down is tests/relight/test_fit.py::test_model_ladder_picks_the_simplest_sufficient_rung, and
what it does on real faces is scripts/eval_outside.py's), and the ladder's choice among rungs."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from relight.fitting._extrapolation import EXTRAPOLATION_FACTOR, extrapolated_highlights
from relight.fitting._model import Layout, pack
from relight.materials import BLINN_PHONG, GGX, LAMBERT


def _ring(n: int, theta_deg: float) -> np.ndarray:
    """n light directions theta from the normal (local frame), evenly in azimuth."""
    t, phi = np.radians(theta_deg), np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.stack([np.sin(t) * np.cos(phi), np.sin(t) * np.sin(phi), np.full(n, np.cos(t))], 1)


def _block(wi: np.ndarray, valid: np.ndarray, bright: float = 0.1):
    """One sample seen from its normal (wo = z): observations ``bright`` in every channel, irradiance 1."""
    N = len(wi)
    w = np.repeat(valid[:, None], 3, 1).astype(np.float32)
    obs = np.full((N, 3), bright, np.float32)
    wo = np.tile([0.0, 0.0, 1.0], (N, 1))
    irr = np.ones((N, 3), np.float32)
    dt = np.dtype(jnp.result_type(float))  # the fit's dtype (float64 under x64)
    return tuple(x[None].astype(dt) for x in (obs, w, wi, wo, irr))


def _flag(model: int, f0: float, alpha: float, data) -> bool:
    lay = Layout(model, False, 0.02)
    p = dict(rho_d=jnp.full(3, 0.3), rho_s=jnp.full(1, f0), alpha=jnp.full(2, alpha), phi=jnp.zeros(()),
             normal=jnp.asarray([0.0, 0.0, 1.0]))
    u = np.asarray(pack(p, lay))[None].astype(data[0].dtype)
    return bool(extrapolated_highlights(u, lay, data, np.arange(1), 8)[0])


def test_a_tall_lobe_between_the_lights_is_flagged_and_a_seen_or_modest_one_is_not():
    """Lights on a ring 40 degrees from the normal: their half vectors are 20 degrees (0.35 rad) off it. A GGX
    lobe of alpha 0.05 reaches half maximum 0.032 rad out and peaks at F D G / 4 ~ 16 (F0 0.5, D = 1 / (pi
    alpha^2)), 160x the brightest observation (0.1): flagged. A light at the peak, valid, unflags it; the same
    light masked (saturated, shadowed) does not. A broad lobe (alpha 0.6) reaches the ring; a tall narrow one
    with F0 small enough to stay under EXTRAPOLATION_FACTOR x the data is not flagged either."""
    ring = _ring(12, 40.0)
    assert _flag(GGX, 0.5, 0.05, _block(ring, np.ones(12, bool)))
    assert _flag(BLINN_PHONG, 0.5, 0.05, _block(ring, np.ones(12, bool)))
    with_peak = np.concatenate([ring, [[0.0, 0.0, 1.0]]])
    assert not _flag(GGX, 0.5, 0.05, _block(with_peak, np.ones(13, bool)))
    assert _flag(GGX, 0.5, 0.05, _block(with_peak, np.r_[np.ones(12, bool), False]))
    assert not _flag(GGX, 0.5, 0.6, _block(ring, np.ones(12, bool)))
    # Peak of F0 D / 4 at normal incidence: below EXTRAPOLATION_FACTOR x 0.1 for F0 small enough.
    f0 = 0.5 * EXTRAPOLATION_FACTOR * 0.1 / (1 / (np.pi * 0.05**2) / 4)
    assert not _flag(GGX, f0, 0.05, _block(ring, np.ones(12, bool)))
    assert not _flag(LAMBERT, 0.5, 0.05, _block(ring, np.ones(12, bool)))


def test_the_ladder_keeps_the_fewest_parameters_and_ggx_between_equals():
    """choose_rungs on closed-form trials (rungs lambert, blinn_phong, ggx, ggx_aniso: 3, 5, 5 and 7
    parameters), 100 held-out and 400 training observations per sample. Each rung's pooled prediction error
    is (100 hmse + 400 tr (400 + p) / (400 - p)) / 500 (Akaike's final prediction error for the training
    part); the tolerance is 2 s^2 sqrt(2 / 500), s^2 the smallest training MSE (1e-4: 1.26e-5). Between
    Blinn-Phong and GGX (as many parameters), GGX unless only Blinn-Phong is within the tolerance."""
    from relight.fitting._ladder import choose_rungs
    from relight.materials import GGX_ANISO

    rungs = (LAMBERT, BLINN_PHONG, GGX, GGX_ANISO)
    hm = np.array([
        [1.0e-4, 1.0e-4, 1.0e-4, 1.0e-4],  # 0: every rung alike: Lambert (its 3 parameters cost least)
        [9.0e-4, 1.02e-4, 1.00e-4, 1.0e-4],  # 1: Blinn-Phong and GGX within; GGX lower -> GGX
        [9.0e-4, 1.00e-4, 1.02e-4, 1.0e-4],  # 2: the same, Blinn-Phong lower but within -> GGX
        [9.0e-4, 9.0e-4, 9.0e-4, 1.0e-4],  # 3: only the anisotropic rung -> ggx_aniso
        [1.0e-4, 1.0e-4, 0.99e-4, 1.0e-4],  # 4: held out alike, Lambert 1.5x the noise in training -> GGX
        [1.1e-4, 0.7e-4, 2.7e-4, 2.7e-4],  # 5: a highlight no held-out observation saw: the rungs without a
        # lobe predict the held-out observations better, but leave 150x the noise in training -> GGX
        [1.0e-4, 1.0e-4, 1.0e-4, 4.0e-4],  # 6: the richest rung fits training noise, pays held out -> Lambert
        [9.0e-4, 1.0e-4, 2.0e-4, 2.0e-4],  # 7: Blinn-Phong lower by 2e-5 pooled, beyond the tolerance -> it
    ])
    tr = np.full(hm.shape, 1e-4)
    tr[4, 0] = 1.5e-4
    tr[5] = [5.7e-2, 4.1e-2, 2.7e-4, 2.7e-4]
    tr[6, 3] = 0.9e-4
    trial = {k: {"hmse": hm[:, i], "rms": np.sqrt(tr[:, i])} for i, k in enumerate(rungs)}
    hmask = np.ones((len(hm), 100, 3))
    n_train = np.full(len(hm), 400)
    choice, heldout = choose_rungs(trial, rungs, hmask, n_train, np.float64)
    assert choice.tolist() == [LAMBERT, GGX, GGX, GGX_ANISO, GGX, GGX, LAMBERT, BLINN_PHONG]
    np.testing.assert_allclose(heldout, np.sqrt(hm[np.arange(len(hm)), [0, 2, 2, 3, 2, 2, 0, 1]]))
    # Within the tolerance (Lambert's training MSE 1.01x the noise), Lambert is kept.
    tr[4, 0] = 1.01e-4
    trial = {k: {"hmse": hm[:, i], "rms": np.sqrt(tr[:, i])} for i, k in enumerate(rungs)}
    assert choose_rungs(trial, rungs, hmask, n_train, np.float64)[0][4] == LAMBERT
    # Fitted normals add two parameters to every rung: the penalty grows, the choices above stay.
    assert choose_rungs(trial, rungs, hmask, n_train, np.float64, True)[0].tolist()[:4] == choice.tolist()[:4]

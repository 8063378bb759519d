"""The public per-sample problems of relight.fitting (docs/fit.md, "Inspecting the per-sample problem"): they
are the fitter's own, so packing, start and one round of the solve reproduce ``relight.fit``, the reference
model agrees with the solver's fast path, and the subsurface texel data of a subset of texels are those rows of
the whole map's.

Scene: the noisy GGX sphere of tests/scenes.py (~80 texels, 42 distant lights of irradiance 1, so the fit's
per-sample normalisation divides by exactly 1), and for the subsurface data a 6 mm sphere's ~130 camera-facing
texels with a 5 mm operator."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdf
import relight
import skin_bssrdf
import stage
from relight.fitting import (
    FitOptions,
    Layout,
    observations,
    predict_radiance,
    residual_and_jacobian,
    rig_alpha_floor,
    solve_samples,
    start_parameters,
    subsurface_texel_data,
)
from relight.materials import GGX

from ..helpers import assert_close
from ..scenes import noisy_ggx_sphere, sphere_view

STEPS = 20


@pytest.fixture(scope="module")
def ggx_sphere():
    return noisy_ggx_sphere(res=16)


def test_observations_pack_every_valid_observation(ggx_sphere):
    cap, surface = ggx_sphere
    obs = observations(cap, surface)
    P, N = surface.num_samples, obs.radiance.shape[1]
    valid = np.asarray(cap.mask).sum(axis=(0, 1))
    assert obs.radiance.shape == (P, N, 3) and obs.wi.shape == (P, N, 3) and obs.light.shape == (P, N)
    assert N >= valid.max() and N % 32 == 0
    np.testing.assert_array_equal(np.asarray(obs.weight)[..., 0].sum(1), valid)
    # Valid first: each sample's weights are a run of ones, then padding.
    w = np.asarray(obs.weight)[..., 0]
    np.testing.assert_array_equal(w, np.arange(N)[None] < valid[:, None])


def test_start_and_one_round_of_the_solve_are_the_fits(ggx_sphere):
    cap, surface = ggx_sphere
    lay = Layout(GGX, False, rig_alpha_floor(cap.rig))
    obs = observations(cap, surface)
    u, _, result, steps, _, _ = solve_samples(start_parameters(obs, lay), obs, lay, max_steps=STEPS)
    f = relight.fit(cap, surface, model="ggx", options=FitOptions(rounds=1, steps_per_round=STEPS))
    ok = ~np.asarray(f.failed)
    assert ok.mean() > 0.9
    # The same start and LM steps on the same float32 observations: the same result codes and step counts, and
    # the albedo to float32 rounding (the last chunk is padded differently in the two, and the code XLA emits
    # for a vmapped lane, tests.helpers.TEST_XLA_FLAGS, may round it differently: measured 1.5e-7 at most).
    assert_close(np.asarray(jax.nn.sigmoid(u[:, :3]))[ok], np.asarray(f.rho_d)[ok], rtol=1e-6, atol=0)
    np.testing.assert_array_equal(np.asarray(result)[ok], np.asarray(f.result)[ok])
    np.testing.assert_array_equal(np.asarray(steps)[ok], np.asarray(f.steps)[ok])


def test_the_reference_model_is_the_solvers(ggx_sphere, key):
    cap, surface = ggx_sphere
    lay = Layout(GGX, True, 0.05)
    obs = observations(cap, surface)
    u = jax.random.normal(key, (lay.size,), jnp.float64)
    wi, wo, irr, rad = (jnp.asarray(x[0]) for x in (obs.wi, obs.wo, obs.irradiance, obs.radiance))

    # Each compiled as one program (op-by-op dispatch compiles every primitive of the model on its own).
    ref = jax.jit(lambda u, wi, wo, irr: predict_radiance(u, lay, wi, wo, irr))(u, wi, wo, irr)
    r, J, pred = jax.jit(lambda u, rad, wi, wo, irr: residual_and_jacobian(
        u, rad.T, jnp.ones_like(rad.T), wi.T, wo.T, irr.T, lay, None))(u, rad, wi, wo, irr)
    assert_close(pred, np.asarray(ref).T)
    assert_close(r, (pred - rad.T).reshape(-1))
    assert J.shape == (r.shape[0], lay.size)


def test_subsurface_texel_data_of_a_subset_are_those_rows():
    _, surface, rig, cam, lv, cv = sphere_view(radius=6.0, res=16, distance=400.0, fov_deg=4, size=64, min_cos=-1.0)
    P = surface.num_samples
    dt = surface.position.dtype
    A = jnp.broadcast_to(jnp.array([0.8, 0.6, 0.45], dt), (P, 3))
    spec = brdf.Microfacet(
        brdf.GGX(jnp.full((P, 1), 0.3, dt)), brdf.SchlickFresnel(jnp.full((P, 1), 0.03, dt)), "smith"
    )
    prof = skin_bssrdf.Burley.from_mean_free_path(A, jnp.full((P, 3), 1.0, dt), config="dmfp")
    op = skin_bssrdf.DiffusionOperator.build(
        np.asarray(surface.position), np.asarray(surface.area), 5.0, dtype=jnp.float64
    )
    cap = stage.simulate(surface, rig, [cam], spec, lv, cv, subsurface=stage.Subsurface(prof, op, skin_bssrdf.SKIN_ETA))
    fitted = relight.fit(cap, surface, model="ggx", loss="cauchy")
    whole = subsurface_texel_data(cap, surface, fitted, op)
    texels = np.array([P - 1, 0, P // 2])
    part = subsurface_texel_data(cap, surface, fitted, op, texels)
    L, K = rig.num_lights, op.index.shape[1]
    assert whole.neighbour_irradiance.shape == (P, 3, L, K) and whole.exitance.shape == (P, L, 3)
    for name, a, b in zip(whole._fields, whole, part, strict=True):
        assert_close(b, np.asarray(a)[texels], err_msg=name)
    assert np.all(np.isfinite(whole.noise_floor)) and np.all(whole.noise_floor > 0) and np.all(whole.unit > 0)

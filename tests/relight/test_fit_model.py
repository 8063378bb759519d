"""The solver's structured forward model (``_fit_model.residual_and_jacobian``)
against the reference composed from ``brdf``'s modules (``_fit_model.predict``)
and forward-mode AD of it, at ordinary and edge configurations; and the
reference against the one OLAT model (``stage.reflected_radiance``,
``stage.simulate``) of the material the fit reports, on every rung."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdf
import stage
from relight.fitting import _model as _fit_model
from relight.fitting._model import BLINN_PHONG, GGX, GGX_ANISO, LAMBERT, Layout

N = 64


def _unit(x):
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def _scene(seed, edge=None):
    """wi [N, 3] (a quarter below the horizon), wo [N, 3], irradiance, observations."""
    rng = np.random.default_rng(seed)
    wi = _unit(rng.normal(size=(N, 3)))
    wi[: 3 * N // 4, 2] = np.abs(wi[: 3 * N // 4, 2])
    wo = np.broadcast_to(_unit(np.array([0.2, -0.1, 1.0])), (N, 3)).copy()
    if edge == "grazing":  # views just above and at the horizon of the surface (below the fitted normal's)
        wo = _unit(np.array([[1.0, 0.3, z] for z in np.linspace(0.0, 0.05, N)]))
        wi[: N // 4] = _unit(np.array([[1.0, 0.0, 1e-7]])).repeat(N // 4, 0)
    if edge == "mirror":  # wi = wo: the half vector is the view itself
        wi[: N // 2] = wo[: N // 2]
    irr = rng.uniform(0.5, 1.5, (N, 3))
    obs = rng.uniform(0.0, 0.6, (N, 3))
    w = (rng.uniform(size=(N, 1)) > 0.1) * np.ones((1, 3))
    return wi, wo, irr, obs, w


@jax.jit(static_argnames=("lay", "c"))
def _reference(u, lay, wi, wo, irr, obs, sw, c):
    def f(v):
        pred = _fit_model.predict(_fit_model.unpack(v, lay), lay, wi, wo, irr)
        return _fit_model.robust(sw * (pred - obs), c).reshape(-1)

    return f(u), jax.jacfwd(f)(u)


@jax.jit(static_argnames=("lay",))
def _predict(u, lay, wi, wo, irr):
    """The reference prediction [N, 3] (the directions as arguments: one compilation per rung, whatever the edge)."""
    return _fit_model.predict(_fit_model.unpack(u, lay), lay, wi, wo, irr)


def _component_major(r_ref, J_ref):
    """Reference [N*3] / [N*3, k] (observation-major) reordered to [3*N] / [3*N, k]."""
    return r_ref.reshape(N, 3).T.reshape(-1), jnp.swapaxes(J_ref.reshape(N, 3, -1), 0, 1).reshape(3 * N, -1)


RUNGS = (LAMBERT, BLINN_PHONG, GGX, GGX_ANISO)
# Every rung at every edge with the normal fitted and the Cauchy loss; and
# every rung with a fixed normal and plain L2.
CASES = ([(m, True, 0.05, e) for m, e in itertools.product(RUNGS, (None, "grazing", "mirror", "floor"))]
         + [(m, False, None, None) for m in RUNGS])


@pytest.mark.parametrize("model,normals,cauchy,edge", CASES)
def test_structured_jacobian_matches_autodiff_of_reference(model, normals, cauchy, edge):
    """Residual to 1e-12 and Jacobian to 1e-9 of max|J| (float64): the two are
    the same function written twice, so only rounding separates them. 'floor'
    puts the roughness at the fit's floor (u -> -8: sigmoid 3e-4 above it)."""
    lay = Layout(model, normals, 0.05)
    wi, wo, irr, obs, w = _scene(model * 7 + normals, edge)
    rng = np.random.default_rng(3)
    u = rng.normal(size=lay.size) * 0.5
    if normals:
        u[-2:] = [0.3, -0.2] if edge != "grazing" else [-0.6, 0.1]  # grazing: tilt away from the views
    if edge == "floor" and model >= BLINN_PHONG:
        u[4] = -8.0
        if model == GGX_ANISO:
            u[5] = -8.0
    sw = np.sqrt(w)
    r_ref, J_ref = _component_major(*_reference(jnp.asarray(u), lay=lay, wi=wi, wo=wo, irr=irr, obs=obs, sw=sw,
                                                c=cauchy))
    T = lambda x: jnp.asarray(x).T  # noqa: E731
    structured = jax.jit(_fit_model.residual_and_jacobian, static_argnames=("lay", "c"))
    r, J, pred = structured(jnp.asarray(u), T(obs), T(sw), T(wi), T(wo), T(irr), lay=lay, c=cauchy)
    assert np.all(np.isfinite(np.asarray(J))) and np.all(np.isfinite(np.asarray(r)))
    np.testing.assert_allclose(r, r_ref, atol=1e-12 * max(1.0, float(jnp.max(jnp.abs(r_ref)))))
    np.testing.assert_allclose(J, J_ref, atol=1e-9 * float(jnp.max(jnp.abs(J_ref))))
    pred_ref = _predict(jnp.asarray(u), lay, wi, wo, irr)
    np.testing.assert_allclose(pred, T(pred_ref), atol=1e-12)


@pytest.mark.parametrize("model", [GGX, GGX_ANISO])
def test_materialised_residual_linearises_to_its_jacobian(model):
    """The custom JVP is J t and its transpose (what BFGS's gradient and the
    normal equations use) is J^T r: both against the reference's AD to 1e-9."""
    lay = Layout(model, True, 0.05)
    wi, wo, irr, obs, w = _scene(11)
    u = jnp.asarray(np.random.default_rng(5).normal(size=lay.size) * 0.4)
    T = lambda x: jnp.asarray(x).T  # noqa: E731
    res = _fit_model.materialised_residual(T(obs), T(np.sqrt(w)), T(wi), T(wo), T(irr), lay, 0.05)
    r_ref, J_ref = _component_major(*_reference(u, lay=lay, wi=wi, wo=wo, irr=irr, obs=obs, sw=np.sqrt(w), c=0.05))
    t = jnp.asarray(np.random.default_rng(6).normal(size=lay.size))
    _, jt = jax.jit(lambda v, d: jax.jvp(res, (v,), (d,)))(u, t)
    scale = float(jnp.max(jnp.abs(J_ref)))
    np.testing.assert_allclose(jt, J_ref @ t, atol=1e-9 * scale * lay.size)
    grad = jax.jit(jax.grad(lambda v: 0.5 * jnp.sum(res(v) ** 2)))(u)
    np.testing.assert_allclose(grad, J_ref.T @ r_ref, atol=1e-9 * scale * N)


# ---------------------------------------------------------------------------
# The reference itself against the one OLAT model (stage._forward) and
# stage.simulate, through the fitted material the driver reports.

P_ONE = 16  # samples per geometry (each its own random frame and parameters)
L_ONE = 48  # lights


def _surface(seed):
    """P_ONE samples near the origin with random shading frames within 40
    degrees of +z (the camera's side), right-handed (t x b = n)."""
    rng = np.random.default_rng(seed)
    n = _unit(rng.normal(size=(P_ONE, 3)) * [0.35, 0.35, 0.0] + [0.0, 0.0, 1.0])
    t = _unit(np.cross(rng.normal(size=(P_ONE, 3)), n))
    b = np.cross(n, t)
    j = jnp.asarray
    return stage.Surface(position=j(rng.uniform(-5.0, 5.0, (P_ONE, 3))), normal=j(n), tangent=j(t), bitangent=j(b),
                         uv=j(np.zeros((P_ONE, 2))), area=j(np.ones(P_ONE)), texel_index=j(np.arange(P_ONE)),
                         face=j(np.zeros(P_ONE, np.int64)), resolution=(1, P_ONE))


def _fitted(lay, surface, seed):
    """Random unconstrained parameters u [P, size] and the Fit the driver
    assembles from them (fitted frame to world, per-rung maps)."""
    from relight.fitting import _ladder, _result

    rng = np.random.default_rng(seed)
    u = rng.normal(size=(P_ONE, lay.size)) * 0.6
    if lay.normals:
        u[:, -2:] *= 0.4  # fitted normals within ~25 degrees of the surface's
    k = len(_ladder._union_index(lay))
    r = dict(u=u, rms=np.zeros(P_ONE), hmse=np.zeros(P_ONE), code=np.zeros(P_ONE, np.int32),
             steps=np.zeros(P_ONE, np.int32), sigma=np.zeros((P_ONE, k)))
    model = np.full(P_ONE, lay.model, np.int32)
    out = _ladder._assemble({lay.model: (np.arange(P_ONE), r)}, model, P_ONE, lay.normals, lay.alpha_floor,
                            np.dtype(np.float64), surface, 64)
    j = jnp.asarray
    f = _result.Fit(rho_d=j(out["rho_d"]), rho_s=j(out["rho_s"]), alpha=j(out["alpha"]), normal=j(out["normal"]),
                    tangent=j(out["tangent"]), model=j(model), residual=j(out["residual"]),
                    heldout=j(np.zeros(P_ONE)), result=j(out["result"]), steps=j(out["steps"]),
                    observed=j(np.full(P_ONE, 100.0)), uncertainty=j(out["uncertainty"]),
                    alpha_floor=lay.alpha_floor)
    return jnp.asarray(u), f


@jax.jit(static_argnames=("lay",))
def _predict_all(u, lay, wi, wo, irr):
    """predict per sample: u [P, k], wi [L, P, 3], wo [P, 3], irr [L, P, C] -> [L, P, C]."""
    one = lambda v, a, b, e: _fit_model.predict(_fit_model.unpack(v, lay), lay, a, jnp.broadcast_to(b, a.shape), e)  # noqa: E731
    return jax.vmap(one, in_axes=(0, 1, 0, 1), out_axes=1)(u, wi, wo, irr)


@pytest.mark.parametrize("model,normals", list(itertools.product(RUNGS, (False, True))))
def test_reference_is_the_one_forward_model_of_the_fitted_material(model, normals):
    """``predict`` (brdf Modules in the fitted frame, view clamp inactive)
    equals ``stage.reflected_radiance`` of ``Fit.material()`` (the LadderBRDF)
    in ``Fit.maps(surface).frame(surface)``, on random frames, parameters and
    directions (a quarter of the lights below each horizon), and equals
    ``stage.simulate`` of that material under a distant-light rig seen by an
    orthographic camera: 1e-12 of the largest radiance (float64; the same
    kernels composed two ways, so only rounding separates them)."""
    lay = Layout(model, normals, 0.05)
    surface = _surface(seed=20 + model)
    u, f = _fitted(lay, surface, seed=30 + model + 4 * normals)
    fr = f.maps(surface).frame(surface)
    material = f.material()

    # Random geometry straight through stage._forward.
    rng = np.random.default_rng(40 + model)
    wi_w = _unit(rng.normal(size=(L_ONE, P_ONE, 3)))
    wo_w = _unit(np.asarray(fr.normal) + 0.5 * rng.normal(size=(P_ONE, 3)))
    wo_w = np.where((np.sum(wo_w * np.asarray(fr.normal), -1, keepdims=True) > 0.1), wo_w, np.asarray(fr.normal))
    irr = jnp.asarray(rng.uniform(0.5, 1.5, (L_ONE, P_ONE, 3)))
    wi_w, wo_w = jnp.asarray(wi_w), jnp.asarray(wo_w)
    ref = stage.reflected_radiance_lights(material, fr.to_local(wi_w), fr.to_local(wo_w), irr)
    pred = _predict_all(u, lay, surface.to_local(wi_w), surface.to_local(wo_w), irr)
    assert float(jnp.max(ref)) > 0 and float(jnp.mean(ref == 0)) > 0.1  # lit and unlit lights both present
    np.testing.assert_allclose(pred, ref, rtol=0, atol=1e-12 * float(jnp.max(jnp.abs(ref))))

    # stage.simulate of the same material on the same samples.
    dirs = np.asarray(brdf.fibonacci_sphere(L_ONE))
    rig = stage.make_rig(dirs, rng.uniform(0.5, 2.0, (L_ONE, 3)), near_field=False)
    f64 = lambda x: jnp.asarray(x, jnp.float64)  # noqa: E731  (make_rig stores float32)
    rig = stage.Rig(position=f64(rig.position), intensity=f64(rig.intensity), solid_angle=f64(rig.solid_angle),
                    near_field=False)
    cam = stage.orthographic((0.0, 0.0, 500.0), (0.0, 0.0, 0.0), extent_mm=40.0, width=32, height=32)
    cap = stage.simulate(fr, rig, [cam], material, np.ones((P_ONE, L_ONE), bool), np.ones((1, P_ONE), bool),
                         dtype=jnp.float64)
    wi_s, wo_s, irr_s = stage.shading_directions(surface, rig, cam)
    pred = _predict_all(u, lay, wi_s, wo_s, irr_s)
    sim = cap.radiance[0]
    assert float(jnp.max(sim)) > 0 and bool(jnp.any(~cap.mask[0]))
    np.testing.assert_allclose(pred, sim, rtol=0, atol=1e-12 * float(jnp.max(jnp.abs(sim))))

"""The solver's structured forward model (``_fit_model.residual_and_jacobian``)
against the reference composed from ``brdf``'s modules (``_fit_model.predict``)
and forward-mode AD of it, at ordinary and edge configurations."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

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
    pred_ref = jax.jit(lambda v: _fit_model.predict(_fit_model.unpack(v, lay), lay, wi, wo, irr))(jnp.asarray(u))
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

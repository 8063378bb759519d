"""Gradients of model-based relighting (``relight.render.render_samples``)
through the shared OLAT forward model, in float64.

Methods "rig" (a near-field dome, light weights from the environment),
"dense" (a lat-long grid of distant lights) and "lights" (a median-cut light
set): jax.grad of a weighted sum of
the relit radiance w.r.t. each material map (rho_d, rho_s, alpha, normal),
contracted with a random direction, and jax.jvp along it, agree with a
central finite difference. Shadows are ray-cast once (not differentiated).
Then the edges: seen at grazing, lit at grazing, alpha at its floor.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdf
import relight
import stage
from relight import render
from relight.envmap import EnvMap
from tests.scenes import uv_sphere

# Central differences in float64 with a step of 1e-5 of each map's scale:
# truncation ~1e-10 and rounding ~1e-11 relative; 1e-6 catches any wrong term.
RTOL = 1e-6
STEP = 1e-5
SCALE = dict(rho_d=1.0, rho_s=0.05, alpha=0.2, normal=1.0)
METHODS = {
    "rig": lambda: dict(rig=stage.geodesic_dome(1, radius_mm=400.0, near_field=True)),  # 42 lights at 8 radii
    "dense": lambda: dict(resolution=8),  # 128 distant lights
    "lights": lambda: dict(lights=48),  # median cut of the 8 x 16 map: 48 regions
}


def _f64(tree):
    return jax.tree_util.tree_map(
        lambda x: x.astype(jnp.float64) if hasattr(x, "dtype") and jnp.issubdtype(x.dtype, jnp.floating) else x, tree)


@pytest.fixture(scope="module")
def scene():
    mesh = uv_sphere(50.0, 8, 16)
    surf = _f64(stage.texel_samples(mesh, 8))
    P = surf.num_samples
    rng = np.random.default_rng(7)
    cam = _f64(stage.look_at((80.0, 60.0, 500.0), fov_deg=20, width=32, height=32))
    wo = cam.view_directions(surf.position)
    env = EnvMap(jnp.asarray(rng.uniform(0.1, 2.0, (8, 16, 3))))
    n = np.asarray(surf.normal)
    maps = dict(rho_d=jnp.asarray(rng.uniform(0.2, 0.8, (P, 3))), rho_s=jnp.asarray(rng.uniform(0.02, 0.1, (P, 1))),
                alpha=jnp.asarray(rng.uniform(0.15, 0.5, (P, 2))),
                # Shading normals tilted off the geometric ones, as a fit gives them.
                normal=jnp.asarray(n + 0.1 * rng.standard_normal((P, 3))))
    weights = jnp.asarray(rng.uniform(0.5, 1.5, (P, 3)))
    # The model map stays concrete (created outside the traced function): the renderer reads it on the host.
    model = jnp.full((P,), relight.MODELS.index("ggx_aniso"), jnp.int32)
    return dict(mesh=mesh, surf=surf, wo=wo, env=env, maps=maps, weights=weights, P=P, model=model,
                mfp=jnp.zeros((P, 3)))


def _maps(sc, p):
    return relight.MaterialMaps(p["rho_d"], p["rho_s"], p["alpha"], p["normal"], sc["surf"].tangent, sc["mfp"],
                                sc["model"])


@pytest.fixture(scope="module", params=sorted(METHODS))
def compiled(request, scene):
    sc = scene
    kw = METHODS[request.param]()

    def f(p):
        out = render.render_samples(_maps(sc, p), sc["surf"], sc["env"], sc["wo"], method=request.param,
                                    mesh=sc["mesh"], dtype=jnp.float64, **kw)
        return jnp.sum(sc["weights"] * out)

    # One program per method: the gradient and the jvp, whose primal output is f (the finite differences
    # read it, so f needs no program of its own; the scene is small, so the gradient computed alongside
    # costs little).
    return dict(method=request.param, both=jax.jit(lambda p, v: (jax.grad(f)(p), jax.jvp(f, (p,), (v,)))))


@pytest.mark.parametrize("name", sorted(SCALE))
def test_render_grad_matches_finite_differences(scene, compiled, name):
    p = scene["maps"]
    rng = np.random.default_rng(sorted(SCALE).index(name))
    v = {k: jnp.zeros_like(x) for k, x in p.items()}
    v[name] = jnp.asarray(rng.standard_normal(p[name].shape) * SCALE[name])
    shift = lambda s: {k: p[k] + s * v[k] for k in p}  # noqa: E731
    f = lambda q: compiled["both"](q, v)[1][0]  # noqa: E731
    fd = float((f(shift(STEP)) - f(shift(-STEP))) / (2 * STEP))
    g, (f0, t) = compiled["both"](p, v)
    assert np.all(np.isfinite(np.asarray(g[name]))), (compiled["method"], name)
    assert abs(fd) > 1e-6 * abs(float(f0))  # the map really moves the result
    np.testing.assert_allclose(float(jnp.vdot(g[name], v[name])), fd, rtol=RTOL, err_msg=compiled["method"])
    np.testing.assert_allclose(float(t), fd, rtol=RTOL, err_msg=compiled["method"])


def test_rig_gradients_finite_at_edges(scene):
    """Method "rig" in float64: samples seen at grazing (cos_o = 1e-7), lights at
    grazing on a near-field dome, alpha at brdf.ALPHA_MIN: finite gradients
    w.r.t. every map, and rho_s still has one."""
    sc = scene
    P = sc["P"]
    n = np.asarray(sc["surf"].normal)
    t = np.asarray(sc["surf"].tangent)
    wo = np.asarray(sc["wo"]).copy()
    wo[: P // 2] = t[: P // 2] * np.sqrt(1 - 1e-14) + n[: P // 2] * 1e-7
    p = dict(sc["maps"], normal=jnp.asarray(n), alpha=jnp.full((P, 2), brdf.ALPHA_MIN))
    rig = stage.geodesic_dome(1, radius_mm=400.0, near_field=True)

    def f(p):
        return jnp.sum(render.render_samples(_maps(sc, p), sc["surf"], sc["env"], jnp.asarray(wo), method="rig",
                                             rig=rig, dtype=jnp.float64))

    g = jax.jit(jax.grad(f))(p)  # one program, as a fit takes it, not hundreds of eagerly dispatched ones
    for k, x in g.items():
        assert np.all(np.isfinite(np.asarray(x))), k
    assert np.any(np.asarray(g["rho_s"]) != 0)

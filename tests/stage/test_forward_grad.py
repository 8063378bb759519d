"""Gradients of the OLAT forward model through ``stage.simulate`` (float64).

For each parameter group -- the material maps (rho_d, f0, alpha of
``brdf.lambert_ggx``), the shading frame and positions (``Surface`` fields),
the near-field rig (light positions and intensities) and the camera pose (a
rotation parameter and t) -- ``jax.grad`` of a weighted sum of the capture's
radiance, contracted with a random direction, and ``jax.jvp`` along that
direction agree with a central finite difference. The visibility is ray-cast
once and held fixed (it is not differentiated). Then the edges: a light at
grazing incidence and alpha at its floor give finite gradients.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdf
import stage

from ..scenes import plane, uv_sphere

# Central differences in float64 with a step of 1e-5 of each group's scale:
# truncation h^2 f''' / 6 ~ 1e-10 and rounding eps / h ~ 1e-11 relative, so
# 1e-6 leaves a wide margin and still catches a wrong term (which is O(1)).
RTOL = 1e-6
STEP = 1e-5


def _f64(tree):
    return jax.tree_util.tree_map(
        lambda x: x.astype(jnp.float64) if hasattr(x, "dtype") and jnp.issubdtype(x.dtype, jnp.floating) else x, tree)


def _cayley(theta):
    """Rotation (I - K)^-1 (I + K) of the skew matrix K of theta [3]: smooth everywhere, identity at 0."""
    x, y, z = theta[0], theta[1], theta[2]
    zero = jnp.zeros_like(x)
    K = jnp.stack([jnp.stack([zero, -z, y]), jnp.stack([z, zero, -x]), jnp.stack([-y, x, zero])])
    eye = jnp.eye(3, dtype=theta.dtype)
    return jnp.linalg.solve(eye - K, eye + K)


@pytest.fixture(scope="module")
def scene():
    mesh = uv_sphere(radius=50.0, n_lat=8, n_lon=16)
    surf = _f64(stage.texel_samples(mesh, 8))
    P = surf.num_samples
    # Six near-field point lights 200-450 mm from the centre (4-9 radii): wi and
    # 1/d^2 vary over the sphere, so positions have a real derivative.
    pos = np.array([[0.0, 0.0, 400.0], [300.0, 100.0, 120.0], [-80.0, 90.0, 160.0], [0.0, -200.0, 150.0],
                    [100.0, 300.0, 300.0], [-250.0, -50.0, 250.0]])
    inten = np.array([[1e5, 2e5, 3e5], [5e4, 5e4, 5e4], [1e4, 2e4, 4e4], [3e5, 1e5, 2e5], [1e5, 1e5, 1e5],
                      [2e5, 1e5, 5e4]])
    rig = _f64(stage.make_rig(pos, inten, near_field=True))
    cam = _f64(stage.look_at((60.0, 40.0, 800.0), fov_deg=12, width=32, height=32))
    lv = stage.light_visibility(mesh, surf, rig)
    cv = stage.camera_visibility(mesh, surf, [cam])
    rng = np.random.default_rng(11)
    maps = (jnp.asarray(rng.uniform(0.2, 0.8, (P, 3))), jnp.asarray(rng.uniform(0.02, 0.1, (P, 1))),
            jnp.asarray(rng.uniform(0.15, 0.5, (P, 1))))
    weights = jnp.asarray(rng.uniform(0.5, 1.5, (1, rig.num_lights, P, 3)))
    assert (np.asarray(lv) & cv[0][:, None]).sum() > 40  # enough lit and seen observations to test
    return dict(mesh=mesh, surf=surf, rig=rig, cam=cam, lv=lv, cv=cv, maps=maps, weights=weights, rng=rng)


def _loss(sc, *, light_chunk=4):
    """Scalar sum(W * radiance) as a function of one dict of parameter groups."""

    def f(p):
        surf = eqx.tree_at(lambda s: (s.position, s.normal, s.tangent, s.bitangent), sc["surf"],
                           (p["position"], p["normal"], p["tangent"], p["bitangent"]))
        rig = stage.Rig(p["light_position"], p["light_intensity"], sc["rig"].solid_angle, near_field=True)
        cam = eqx.tree_at(lambda c: (c.R, c.t), sc["cam"], (_cayley(p["theta"]) @ sc["cam"].R, p["t"]))
        mat = brdf.lambert_ggx(p["rho_d"], p["f0"], p["alpha"])
        cap = stage.simulate(surf, rig, [cam], mat, sc["lv"], sc["cv"], dtype=jnp.float64, light_chunk=light_chunk)
        return jnp.sum(sc["weights"] * cap.radiance)

    return f


def _params(sc):
    s, r = sc["surf"], sc["rig"]
    return dict(rho_d=sc["maps"][0], f0=sc["maps"][1], alpha=sc["maps"][2], position=s.position, normal=s.normal,
                tangent=s.tangent, bitangent=s.bitangent, light_position=r.position, light_intensity=r.intensity,
                theta=jnp.asarray([0.01, -0.02, 0.005]), t=sc["cam"].t)


# The scale of each group: a step of STEP times this moves it by a comparable relative amount.
SCALE = dict(rho_d=1.0, f0=0.1, alpha=0.3, position=1.0, normal=1.0, tangent=1.0, bitangent=1.0,
             light_position=100.0, light_intensity=1e5, theta=1.0, t=10.0)
GROUPS = {
    "material": ("rho_d", "f0", "alpha"),
    "normals": ("normal",),
    "frame_and_position": ("tangent", "bitangent", "position"),
    "lights": ("light_position", "light_intensity"),
    "camera": ("theta", "t"),
}


@pytest.fixture(scope="module")
def compiled(scene):
    # One program: the gradient and the jvp, whose primal output is f (the finite differences read it, so f
    # needs no program of its own; the scene is small, so the gradient computed alongside costs little).
    f = _loss(scene)
    return dict(both=jax.jit(lambda p, v: (jax.grad(f)(p), jax.jvp(f, (p,), (v,)))))


@pytest.mark.parametrize("group", sorted(GROUPS))
def test_grad_and_jvp_match_finite_differences(scene, compiled, group):
    p = _params(scene)
    rng = np.random.default_rng(sorted(GROUPS).index(group))
    zero = {k: jnp.zeros_like(x) for k, x in p.items()}
    v = dict(zero)
    for k in GROUPS[group]:
        v[k] = jnp.asarray(rng.standard_normal(p[k].shape) * SCALE[k])
    shift = lambda s: {k: p[k] + s * v[k] for k in p}  # noqa: E731
    f = lambda q: compiled["both"](q, v)[1][0]  # noqa: E731
    fd = (f(shift(STEP)) - f(shift(-STEP))) / (2 * STEP)
    g, (f0, t) = compiled["both"](p, v)
    g_v = sum(jnp.vdot(g[k], v[k]) for k in GROUPS[group])
    assert abs(float(fd)) > 1e-6 * abs(float(f0))  # the group really moves the capture
    for k in GROUPS[group]:
        assert np.all(np.isfinite(np.asarray(g[k]))), k
    np.testing.assert_allclose(float(g_v), float(fd), rtol=RTOL)
    np.testing.assert_allclose(float(t), float(fd), rtol=RTOL)


def test_eager_grad_equals_jitted(scene, compiled):
    # Un-jitted jax.grad runs simulate's host loop with tracers (the traced assembly path).
    p = _params(scene)
    f = _loss(scene, light_chunk=4)
    g_eager = jax.grad(lambda q: f({**p, **q}))({k: p[k] for k in GROUPS["material"] + GROUPS["camera"]})
    g_jit, _ = compiled["both"](p, p)
    for k, x in g_eager.items():
        np.testing.assert_allclose(np.asarray(x), np.asarray(g_jit[k]), rtol=1e-12, atol=1e-12)


def test_traced_capture_equals_concrete(scene):
    # The traced path (jnp assembly, traced masks) gives the concrete capture's radiance and mask.
    sc = scene
    mat = brdf.lambert_ggx(*sc["maps"])
    run = lambda m: stage.simulate(sc["surf"], sc["rig"], [sc["cam"]], m, sc["lv"], sc["cv"],  # noqa: E731
                                   dtype=jnp.float64, light_chunk=4)
    ref = run(mat)
    traced = jax.jit(lambda m: (lambda c: (c.radiance, c.mask))(run(m)))(mat)
    np.testing.assert_allclose(np.asarray(traced[0]), np.asarray(ref.radiance), rtol=1e-12, atol=0)
    np.testing.assert_array_equal(np.asarray(traced[1]), np.asarray(ref.mask))


def test_gradients_finite_at_grazing_light_and_alpha_floor():
    """A plane lit at grazing incidence (cos_i ~ 5e-8 for the first light) and
    from above, seen from above and near grazing, with alpha at brdf.ALPHA_MIN
    (and below it, where the floor holds): every gradient is finite."""
    mesh = plane(size=20.0, n=2)
    surf = _f64(stage.texel_samples(mesh, 4))
    P = surf.num_samples
    rig = _f64(stage.make_rig(np.array([[2000.0, 1e-4, 0.0], [0.0, 500.0, 0.0], [300.0, 300.0, 100.0],
                                             [0.0, -500.0, 0.0]]), 1e5))
    cams = [_f64(stage.look_at((0.0, 600.0, 1.0), fov_deg=10, width=16, height=16)),
            _f64(stage.look_at((0.0, 1e-3, 900.0), fov_deg=10, width=16, height=16))]
    # Visibility given, not ray-cast: the ray origins' offset off the plane (3e-3 mm) would put
    # the grazing light below their horizon. The light below is shadowed.
    lv = np.ones((P, 4), bool)
    lv[:, 3] = False
    cv = np.ones((2, P), bool)
    alpha = jnp.asarray(np.r_[np.full(P // 2, brdf.ALPHA_MIN), np.full(P - P // 2, 1e-6)][:, None])

    def f(rho_d, f0, alpha, normal, light_position, theta):
        s = eqx.tree_at(lambda s: s.normal, surf, normal)
        r = stage.Rig(light_position, rig.intensity, rig.solid_angle, near_field=True)
        c = [eqx.tree_at(lambda c: c.R, cams[0], _cayley(theta) @ cams[0].R), cams[1]]
        cap = stage.simulate(s, r, c, brdf.lambert_ggx(rho_d, f0, alpha), lv, cv, dtype=jnp.float64)
        return jnp.sum(cap.radiance)

    args = (jnp.full((P, 3), 0.5), jnp.full((P, 1), 0.04), alpha, surf.normal, rig.position, jnp.zeros(3))
    # One program for the gradient and the jvp. Jitted: the eager path with tracers is
    # test_eager_grad_equals_jitted's; op by op it costs ~3x the compile.
    tangents = tuple(jnp.ones_like(a) for a in args)
    grads, (_, t) = jax.jit(lambda *a: (jax.grad(f, argnums=tuple(range(len(args))))(*a),
                                        jax.jvp(f, a, tangents)))(*args)
    for name, g in zip(("rho_d", "f0", "alpha", "normal", "light_position", "theta"), grads, strict=True):
        assert np.all(np.isfinite(np.asarray(g))), name
    assert np.any(np.asarray(grads[4])[0] != 0)  # the grazing light's position still has a derivative
    assert np.isfinite(float(t))

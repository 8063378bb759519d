"""relight.render method "lights": the median-cut light set (Debevec 2005) with
ray-cast shadows. The partition conserves the map's integral, converges to
the midpoint rule of the map at full resolution ("dense" at the map's rows,
equal to rounding once every region is one pixel), agrees with the Monte Carlo
reference on the head with cast shadows (also under a rotated environment),
and is differentiable in the environment. (The white furnace is in
test_render.py, the gradients against finite differences in test_render_grad.py.)"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import relight
import stage
from relight import render
from relight.envmap import EnvMap, latlong_solid_angles, rotation_matrix
from relight.render._lights import median_cut, region_strength
from tests.helpers import REFUSED

from ..scenes import envmap


@pytest.fixture(scope="module")
def head_grace():
    """The head at 24 x 24 texels (cast shadows) under grace area-resampled to 32 x 64."""
    from tests.conftest import SHARED_DATA

    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data not found at {SHARED_DATA}")
    from relight.render._fast import area_resample

    env = EnvMap(area_resample(jnp.asarray(envmap(SHARED_DATA, "grace").radiance, jnp.float32), 32))
    mesh = stage.load_head()
    surf = stage.texel_samples(mesh, 24)
    cam = stage.look_at((0.0, 0.0, 700.0), fov_deg=30, width=64, height=64)
    wo = cam.view_directions(surf.position)
    maps = relight.material_maps(surf, np.array([0.6, 0.42, 0.33]), 0.04, 0.3)
    facing = np.sum(np.asarray(wo) * np.asarray(surf.normal), axis=1) > 0
    return mesh, surf, maps, env, wo, facing


def _rel(x, ref, mask):
    x, ref = np.asarray(x, np.float64)[mask], np.asarray(ref, np.float64)[mask]
    return float(np.sqrt(np.mean((x - ref) ** 2) / np.mean(ref**2)))


def test_median_cut_conserves_the_map_and_splits_energy_evenly():
    """Labels cover every pixel with K regions; the strengths sum to int L dw
    (float64 rounding); on a smooth map no region holds more than 2.5x the
    mean energy (a cut halves energy up to one pixel row); K = H W gives one
    region per pixel with its centre direction; a black map gives zeros, no NaN."""
    rng = np.random.default_rng(0)
    h, w = 16, 32
    rad = np.exp(rng.normal(0, 0.3, (h, w, 3)))
    dom = np.asarray(latlong_solid_angles(h, w, jnp.float64))
    for K in (7, 64, 200):
        labels, dirs = median_cut(rad, K)
        assert labels.shape == (h, w) and dirs.shape == (K, 3)
        assert set(np.unique(labels)) == set(range(K))
        np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-12)
        phi = np.asarray(region_strength(jnp.asarray(rad), labels, K))
        np.testing.assert_allclose(phi.sum(0), (rad * dom[..., None]).sum((0, 1)), rtol=1e-10)
        lum = phi @ [0.2126, 0.7152, 0.0722]
        assert lum.max() < 2.5 * lum.mean(), (K, lum.max() / lum.mean())
    labels, dirs = median_cut(rad, h * w + 10)  # capped at one region per pixel
    assert dirs.shape == (h * w, 3)
    centre = np.asarray(relight.envmap.latlong_directions(h, w, jnp.float64)).reshape(-1, 3)
    np.testing.assert_allclose(dirs[labels.reshape(-1)], centre, atol=1e-12)
    labels, dirs = median_cut(np.zeros((h, w, 3)), 32)
    assert np.all(np.isfinite(dirs)) and dirs.shape == (32, 3)
    assert np.all(np.asarray(region_strength(jnp.zeros((h, w, 3)), labels, 32)) == 0)


def test_lights_converge_to_the_full_resolution_midpoint_rule(head_grace):
    """Head with cast shadows, grace at 32 x 64: against "dense" at the map's own
    32 rows (the exact answer of the piecewise-constant map up to the midpoint
    rule per pixel), the relative RMS error falls with K (measured 1.9%, 0.69%,
    0.10% at 64, 256, 1024 lights) and vanishes to float32 rounding at K = 2048
    (every region one pixel: the same sum)."""
    mesh, surf, maps, env, wo, facing = head_grace
    dense = render.render_samples(maps, surf, env, wo, method="dense", resolution=32, mesh=mesh)
    errs = [_rel(render.render_samples(maps, surf, env, wo, method=render.Lights(lights=k), mesh=mesh), dense, facing)
            for k in (64, 256, 1024)]
    assert errs[0] > errs[1] > errs[2], errs
    assert errs[0] < 0.03 and errs[1] < 0.012 and errs[2] < 3e-3, errs
    full = render.render_samples(maps, surf, env, wo, method="lights", lights=2048, mesh=mesh)
    np.testing.assert_allclose(np.asarray(full), np.asarray(dense), atol=1e-5 * float(np.max(dense)))


def test_lights_agree_with_the_reference_also_rotated(head_grace):
    """Against the Monte Carlo reference (512 spp, MIS, its own rays): 1024
    lights are as close as the exact quadrature is ("dense" at the map's rows;
    the residual is the reference's noise, ~5% here) within 10% of that
    distance, below 8%; under the environment rotated by 1.2 rad about y
    (lights moved, their shadows re-cast) within 8% of the rotated reference,
    and the unrotated render is > 4x farther from it (measured 2.8% vs 37%)."""
    mesh, surf, maps, env, wo, facing = head_grace
    key = jax.random.PRNGKey(1)
    ref = render.render_samples(maps, surf, env, wo, method="reference", samples=512, mesh=mesh, key=key)
    dense = render.render_samples(maps, surf, env, wo, method="dense", resolution=32, mesh=mesh)
    lights = render.render_samples(maps, surf, env, wo, method=render.Lights(lights=1024), mesh=mesh)
    e_l, e_d = _rel(lights, ref, facing), _rel(dense, ref, facing)
    assert e_l < 0.08 and e_l < 1.1 * e_d, (e_l, e_d)
    R = np.asarray(rotation_matrix(jnp.asarray([0.0, 1.0, 0.0]), jnp.asarray(1.2)), np.float64)
    ref_r = render.render_samples(maps, surf, env, wo, method="reference", samples=512, mesh=mesh, key=key,
                                  rotation=R)
    rot = render.render_samples(maps, surf, env, wo, method=render.Lights(lights=1024), mesh=mesh, rotation=R)
    e_r, e_u = _rel(rot, ref_r, facing), _rel(lights, ref_r, facing)
    assert e_r < 0.08 and e_u > 4 * e_r, (e_r, e_u)
    assert np.all(np.isfinite(np.asarray(rot)))


def test_lights_gradient_in_the_environment_matches_finite_differences():
    """float64, a sphere (horizon-clipped): the radiance is linear in the map
    for a fixed partition; with one region per pixel (K = H W = 128) the
    partition does not depend on the values, so jax.grad along a random
    direction of the environment equals a central difference to 1e-8 relative.
    With 32 regions (cut from the values, held fixed) the gradient is finite
    and positive."""
    from tests.scenes import uv_sphere

    mesh = uv_sphere(50.0, 8, 16)
    surf = jax.tree_util.tree_map(lambda x: x.astype(jnp.float64) if hasattr(x, "dtype") and
                                  jnp.issubdtype(x.dtype, jnp.floating) else x, stage.texel_samples(mesh, 8))
    rng = np.random.default_rng(2)
    P = surf.num_samples
    maps = relight.material_maps(surf, rng.uniform(0.2, 0.8, (P, 3)), 0.05, 0.3)
    wo = jnp.asarray(np.asarray(surf.normal), jnp.float64)
    rad = jnp.asarray(rng.uniform(0.1, 2.0, (8, 16, 3)))

    def f(r, k=128):
        out = render.render_samples(maps, surf, EnvMap(r), wo, method=render.Lights(lights=k), mesh=mesh,
                                    dtype=jnp.float64)
        return jnp.sum(out)

    g32 = np.asarray(jax.grad(lambda r: f(r, 32))(rad))
    assert np.all(np.isfinite(g32)) and np.all(g32 >= 0) and np.any(g32 > 0)
    g = jax.grad(f)(rad)
    v = jnp.asarray(rng.standard_normal(rad.shape))
    h = 1e-3
    fd = (f(rad + h * v) - f(rad - h * v)) / (2 * h)
    np.testing.assert_allclose(float(jnp.vdot(g, v)), float(fd), rtol=1e-8)


def test_lights_refuses_bad_settings_and_a_traced_environment():
    with pytest.raises(ValueError, match="lights"):
        render.Lights(lights=0)
    with pytest.raises(REFUSED):  # a non-integer: the annotation (strict jaxtyping) or the check
        render.Lights(lights=2.5)
    surf = stage.texel_samples(stage.load_head(), 4)
    maps = relight.material_maps(surf, 0.5)

    @jax.jit
    def f(r):
        return render.render_samples(maps, surf, EnvMap(r), np.asarray(surf.normal), method="lights")

    with pytest.raises(ValueError, match="concrete env"):
        f(jnp.ones((8, 16, 3), jnp.float32))


def test_lights_turntable_recasts_the_rotated_lights_shadows():
    """An envmap turntable with "lights" on the head (cast shadows): frame 1 is
    render_view with the environment rotated by a quarter turn (the lights
    rotated, their shadow rays cast anew, not the cached unrotated mask), to
    float32 rounding, and differs from frame 0."""
    mesh = stage.load_head()
    surf = stage.texel_samples(mesh, 12)
    maps = relight.material_maps(surf, 0.6, 0.05, 0.3)
    d = np.asarray(relight.envmap.latlong_directions(16, 32), np.float32)
    cap = 0.1 + 4.0 * (d[..., :1] > 0.7) * np.ones(3)  # a bright cap toward +x
    env = EnvMap(jnp.asarray(cap.astype(np.float32)))
    cam = stage.look_at((0.0, 0.0, 700.0), fov_deg=30, width=12, height=12)
    method = render.Lights(lights=32)
    frames = list(render.turntable(maps, surf, mesh, cam, env, frames=4, method=method, supersample=1))
    rot = np.asarray(rotation_matrix(jnp.asarray([0.0, 1.0, 0.0]), jnp.asarray(np.pi / 2)), np.float64)
    one = render.render_view(maps, surf, mesh, cam, env, method=method, supersample=1, rotation=rot)
    np.testing.assert_allclose(frames[1], one, rtol=1e-5, atol=1e-6)
    assert np.abs(frames[1] - frames[0]).max() > 0.1 * frames[0].max()
    assert all(np.all(np.isfinite(f)) for f in frames)

"""Rigs with zero-intensity lights (built by hand: stage.make_rig may refuse
them, a rig.json or a Rig(...) need not): the light weights and the relighting
built on them treat a light of zero irradiance as absent (weight 0, its
directions go to the present lights, energy conserved), refuse a rig with no
positive light by name, and never give NaN or Inf."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdf
import stage
from relight import material_maps
from relight.envmap import (
    EnvMap,
    envmap_integral,
    light_weights,
    light_weights_barycentric,
    rotation_matrix,
    rotation_sweep_weights,
)
from relight.render import Rig, image_based_view, render_samples


def _env(seed=0, h=16):
    rng = np.random.default_rng(seed)
    return EnvMap(jnp.asarray(rng.uniform(0.0, 2.0, (h, 2 * h, 3)), jnp.float64))


def _rig(dirs, intensity, near_field=False, radius=1000.0):
    d = np.asarray(dirs, np.float64)
    inten = np.asarray(intensity, np.float64)
    return stage.Rig(position=jnp.asarray(d * (radius if near_field else 1.0), jnp.float32),
                     intensity=jnp.asarray(inten, jnp.float32),
                     solid_angle=jnp.full((len(d),), 4 * np.pi / len(d), jnp.float32), near_field=near_field)


DIRS = brdf.fibonacci_sphere(42)


@pytest.mark.parametrize("weights", [light_weights, light_weights_barycentric])
def test_all_zero_rig_is_refused_by_name(weights):
    env = _env()
    with pytest.raises(ValueError, match="no positive light cannot relight"):
        weights(env, DIRS, np.zeros((42, 3)))
    with pytest.raises(ValueError, match="no positive light cannot relight"):
        rotation_sweep_weights(env, DIRS, np.zeros(42), np.eye(3)[None],
                               method="voronoi" if weights is light_weights else "barycentric")


@pytest.mark.parametrize("bad, match", [(-1.0, "finite and >= 0"), (np.nan, "finite and >= 0"),
                                        (np.inf, "finite and >= 0"), ("mixed", "zero in some channels only")])
def test_bad_irradiance_is_refused_naming_the_light(bad, match):
    e = np.ones((42, 3))
    if bad == "mixed":
        e[7, 1] = 0.0
    else:
        e[7] = bad
    with pytest.raises(ValueError, match=rf"(?=.*{match})(?=.*light\(s\) \[7\])"):
        light_weights(_env(), DIRS, e)


@pytest.mark.parametrize("weights", [light_weights, light_weights_barycentric])
def test_zero_lights_are_absent_and_energy_is_conserved(weights):
    """Zero lights: weight exactly 0; the others equal the weights of the rig
    without them (their cells absorb the absent lights' directions); and
    sum_l w_l E_l is still the map's integral (float64, 1e-10 relative)."""
    env = _env(1)
    rng = np.random.default_rng(2)
    e = rng.uniform(0.5, 2.0, (42, 3))
    absent = np.array([0, 5, 6, 17, 41])
    e[absent] = 0.0
    keep = np.setdiff1d(np.arange(42), absent)
    w = np.asarray(weights(env, DIRS, e))
    assert np.all(np.isfinite(w)) and np.all(w >= 0)
    assert np.all(w[absent] == 0.0)
    np.testing.assert_allclose(w[keep], np.asarray(weights(env, DIRS[keep], e[keep])), rtol=1e-12, atol=0)
    total = np.asarray(envmap_integral(env), np.float64)
    np.testing.assert_allclose((w * e).sum(0), total, rtol=1e-10)
    # A rotation sweep gives the same as the one-frame weights of each rotated rig.
    R = np.asarray(rotation_matrix(np.array([0.0, 1.0, 0.0]), 0.7), np.float64)
    method = "voronoi" if weights is light_weights else "barycentric"
    sweep = np.asarray(rotation_sweep_weights(env, DIRS, e, np.stack([np.eye(3), R]), method=method))
    np.testing.assert_allclose(sweep[0], w, rtol=1e-12, atol=1e-300)
    assert np.all(sweep[1][absent] == 0.0) and np.all(np.isfinite(sweep))
    np.testing.assert_allclose((sweep[1] * e).sum(0), total, rtol=1e-10)


def test_traced_zero_lights_give_zero_weights_not_inf():
    """Under jit the irradiance cannot be inspected: the division is guarded,
    so a zero light's weight is 0 (its cell's energy is then lost, but never
    NaN or Inf)."""
    env = _env(3)
    e = np.ones((42, 3))
    e[3] = 0.0
    w = np.asarray(jax.jit(lambda x: light_weights(env, DIRS, x))(jnp.asarray(e)))
    assert np.all(np.isfinite(w)) and np.all(w[3] == 0.0)
    # The other lights keep their own cells (the partition still includes light 3).
    lit = np.asarray(light_weights(env, DIRS, np.ones((42, 3))))
    np.testing.assert_allclose(np.delete(w, 3, 0), np.delete(lit, 3, 0), rtol=1e-12)


def _sphere_capture(intensity):
    """A 12-light rig around a unit-albedo sphere, rendered in texel space without shadows."""
    from tests.scenes import uv_sphere

    mesh = uv_sphere(radius=50.0, n_lat=12, n_lon=24)
    surf = stage.texel_samples(mesh, 32)
    dirs = brdf.fibonacci_sphere(12)
    rig = _rig(dirs, intensity, near_field=True)
    cam = stage.look_at((0.0, 0.0, 600.0), fov_deg=14, width=32, height=32)
    P = surf.num_samples
    material = brdf.lambert_ggx(jnp.full((P, 3), 0.5, jnp.float32), jnp.full((P, 1), 0.04, jnp.float32),
                                jnp.full((P, 1), 0.3, jnp.float32))
    cap = stage.simulate(surf, rig, [cam], material, np.ones((P, 12), bool), np.ones((1, P), bool))
    return cap, surf, mesh, cam, rig


def test_image_based_view_of_a_zero_rig():
    env = _env(4)
    cap, surf, mesh, cam, _ = _sphere_capture(np.zeros((12, 3)))
    with pytest.raises(ValueError, match="no positive light cannot relight"):
        image_based_view(cap, surf, mesh, cam, env)
    # Some lights at zero: a finite image, equal to relighting the capture without them.
    inten = np.ones((12, 3))
    inten[[2, 9]] = 0.0
    cap, surf, mesh, cam, _ = _sphere_capture(inten)
    img = image_based_view(cap, surf, mesh, cam, env)
    assert np.all(np.isfinite(img)) and img.max() > 0
    ref = image_based_view(cap.lights(np.setdiff1d(np.arange(12), [2, 9])), surf, mesh, cam, env)
    np.testing.assert_allclose(img, ref, rtol=1e-5, atol=1e-7)


def test_model_based_rig_method_with_zero_lights():
    """render_samples(method="rig") on a rig with absent lights is finite and
    equals the render on the rig without them; an all-zero rig is refused."""
    from tests.scenes import uv_sphere

    mesh = uv_sphere(radius=50.0, n_lat=12, n_lon=24)
    surf = stage.texel_samples(mesh, 16)
    maps = material_maps(surf, np.array([0.6, 0.4, 0.3]), 0.04, 0.3)
    env = EnvMap(jnp.asarray(_env(5).radiance, jnp.float32))
    dirs = brdf.fibonacci_sphere(42)
    inten = np.ones((42, 1))
    inten[[1, 20, 33]] = 0.0
    keep = np.setdiff1d(np.arange(42), [1, 20, 33])
    wo = np.array([0.0, 0.0, 1.0])
    out = np.asarray(render_samples(maps, surf, env, wo, method=Rig(rig=_rig(dirs, inten))))
    ref = np.asarray(render_samples(maps, surf, env, wo, method=Rig(rig=_rig(dirs[keep], inten[keep]))))
    assert np.all(np.isfinite(out)) and out.max() > 0
    np.testing.assert_allclose(out, ref, rtol=1e-5, atol=1e-7)
    with pytest.raises(ValueError, match="no positive light cannot relight"):
        render_samples(maps, surf, env, wo, method=Rig(rig=_rig(dirs, np.zeros((42, 1)))))

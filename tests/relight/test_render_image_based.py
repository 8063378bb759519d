"""Image-based relighting through a novel camera (``relight.render.image_based_view``,
``nearest_view``): the Debevec et al. 2000 weighted sum over a rig, looked up per
texel in the nearest captured view that sees it."""

import jax.numpy as jnp
import numpy as np
import pytest

import stage
from relight.envmap import EnvMap
from relight.image import dilate, texture_view
from relight.render import image_based_view, nearest_view

RES = 12
SIZE = 24


@pytest.fixture(scope="module")
def scene():
    mesh = stage.load_head()
    full = stage.texel_samples(mesh, RES)
    surface = full.subset(np.arange(0, full.num_samples, 2))
    rig = stage.geodesic_dome(0)  # 12 distant lights
    cams = stage.camera_ring(2, 1300.0, fov_deg=11.0, width=SIZE, height=SIZE, start_deg=-30.0, arc_deg=60.0)
    return mesh, surface, rig, cams


def _constant_env(c):
    return EnvMap(np.full((16, 32, 3), c, np.float32))


def _capture(surface, rig, cams, albedo_per_view):
    """OLAT_l = E_l * a_v(p): every light, scaled by its own irradiance at the
    centre, gives the same image, so a constant environment c relights it to
    c * a_v * (sum of the Voronoi cells) = 4 pi c a_v."""
    E = np.asarray(rig.center_irradiance, np.float64)  # [L, C]
    rad = np.stack([E[:, None, :] * a[None] for a in albedo_per_view])  # [V, L, P, C]
    mask = np.ones(rad.shape[:3], bool)
    return stage.Capture(radiance=jnp.asarray(rad, jnp.float32), mask=jnp.asarray(mask), rig=rig, cameras=tuple(cams))


def _seen_through(mesh, surface, camera, values):
    covered = np.zeros(surface.resolution, bool)
    covered.reshape(-1)[np.asarray(surface.texel_index)] = True
    tex = dilate(surface.to_texture(np.asarray(values, np.float32)), covered)
    return texture_view(mesh, camera, {"v": tex})["v"]


def test_constant_environment_gives_four_pi_times_the_albedo(scene):
    mesh, surface, rig, cams = scene
    rng = np.random.default_rng(0)
    a = rng.uniform(0.2, 0.8, (surface.num_samples, 3))
    capture = _capture(surface, rig, cams[:1], [a])
    frames = []
    out = image_based_view(capture, surface, mesh, cams[0], _constant_env(0.5), progress=lambda *a: frames.append(a))
    assert out.shape == (1, SIZE, SIZE, 3) and out.dtype == np.float32
    assert frames == [("image-based relighting", 0, 1), ("image-based relighting", 1, 1)]
    expected = 4 * np.pi * 0.5 * _seen_through(mesh, surface, cams[0], a)
    assert (expected > 0).mean() > 0.2
    # The Voronoi cells partition the sphere: exact up to the map's pixelisation
    # of the cells (the sum of the weights is exact to ~1e-6).
    np.testing.assert_allclose(out[0], expected, rtol=1e-5, atol=1e-6)
    # A constant environment does not change when turned.
    rots = np.stack([np.eye(3), np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]])])
    turned = image_based_view(capture, surface, mesh, cams[0], _constant_env(0.5), rotations=rots)
    np.testing.assert_allclose(turned[1], turned[0], rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match=r"rotations must be \[K, 3, 3\]"):
        image_based_view(capture, surface, mesh, cams[0], _constant_env(0.5), rotations=np.eye(3))


def test_each_texel_comes_from_the_nearest_captured_view(scene):
    """View 1 recorded twice the radiance of view 0: a camera next to view 1
    sees view 1's values, one next to view 0 sees view 0's."""
    mesh, surface, rig, cams = scene
    a = np.full((surface.num_samples, 3), 0.3)
    capture = _capture(surface, rig, cams, [a, 2 * a])
    near0 = stage.look_at(np.asarray(cams[0].center) * 1.01, fov_deg=11.0, width=SIZE, height=SIZE)
    near1 = stage.look_at(np.asarray(cams[1].center) * 1.01, fov_deg=11.0, width=SIZE, height=SIZE)
    assert np.all(nearest_view(capture, near0) == 0) and np.all(nearest_view(capture, near1) == 1)
    env = _constant_env(1.0)
    img0 = image_based_view(capture, surface, mesh, near0, env)[0]
    img1 = image_based_view(capture, surface, mesh, near1, env)[0]
    np.testing.assert_allclose(img0, 4 * np.pi * _seen_through(mesh, surface, near0, a), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(img1, 4 * np.pi * _seen_through(mesh, surface, near1, 2 * a), rtol=1e-5, atol=1e-6)


def test_nearest_view_takes_only_views_that_see_the_texel():
    """Per texel, the capture view closest in direction to the render camera
    among those that see it (so specular highlights come from the best view)."""
    left, front, right = (stage.look_at((x, 0.0, 1300.0)) for x in (-900.0, 0.0, 900.0))
    mask = np.zeros((3, 2, 4), bool)  # [V, L, P]
    mask[:, :, 0] = True  # seen by all: the front view wins for a front camera
    mask[0, 1, 1] = mask[2, 0, 1] = True  # seen by left and right only
    mask[2, 0, 2] = True  # seen by right only
    mask[0, 0, 3] = True  # seen by left only
    rig = stage.Rig(position=jnp.eye(3)[:2] * 1000.0, intensity=jnp.ones((2, 1)), solid_angle=jnp.full((2,), 2 * np.pi),
                    near_field=False)
    capture = stage.Capture(radiance=jnp.zeros((3, 2, 4, 1)), mask=jnp.asarray(mask), rig=rig,
                            cameras=(left, front, right))
    near_right = stage.look_at((300.0, 0.0, 1300.0))
    np.testing.assert_array_equal(nearest_view(capture, near_right), [1, 2, 2, 0])

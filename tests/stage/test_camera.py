import jax
import numpy as np

import stage


def test_project_and_rays_round_trip():
    cam = stage.look_at((300.0, 200.0, 1500.0), target=(0, 0, 0), fov_deg=20, width=640, height=480)
    pts = np.random.default_rng(0).uniform(-100, 100, size=(50, 3)).astype(np.float32)
    pix, z = cam.project(pts)
    origin, d = cam.rays(pix)
    # The ray through a point's pixel passes through the point: origin + z_dist * d = point.
    dist = np.linalg.norm(pts - np.asarray(origin), axis=1)
    np.testing.assert_allclose(np.asarray(origin) + dist[:, None] * np.asarray(d), pts, atol=1e-2)
    assert np.all(np.asarray(z) > 0)


def test_target_projects_to_image_centre():
    cam = stage.look_at((0.0, 0.0, 1000.0), width=200, height=100)
    pix, _ = cam.project(np.zeros((1, 3), np.float32))
    np.testing.assert_allclose(np.asarray(pix)[0], [100.0, 50.0], atol=1e-4)
    np.testing.assert_allclose(np.asarray(cam.center), [0, 0, 1000.0], atol=1e-3)
    # World up (+y) appears up in the image (smaller row index) in the OpenCV convention.
    pix_up, _ = cam.project(np.array([[0.0, 10.0, 0.0]], np.float32))
    assert float(pix_up[0, 1]) < 50.0


def test_camera_is_a_pytree_under_jit():
    cam = stage.look_at((0.0, 0.0, 1000.0))
    f = jax.jit(lambda c, p: c.project(p)[0])
    p = np.array([[10.0, 5.0, 0.0]], np.float32)
    np.testing.assert_allclose(np.asarray(f(cam, p)), np.asarray(cam.project(p)[0]), rtol=1e-6)

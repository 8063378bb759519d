"""Camera files in OpenCV's pixel convention and OpenCV's lens distortion (issue 28, item 1).

The distortion is checked against kornia's independent implementation of OpenCV's model
(``kornia.geometry.calibration.distort_points``, pixel coordinates with integer pixel centres), the pixel
convention against OpenCV's definition (the top-left pixel's centre is (0, 0)), and the inverse map
(``Camera.rays``) against the forward one (``Camera.project``)."""

import json
import warnings

import jax.numpy as jnp
import numpy as np
import pytest

import stage

DIST = np.array([-0.21, 0.07, 0.0012, -0.0008, -0.015])  # a real lens: 5% barrel at the corner


def _camera(dist=DIST, width=640, height=480, f=600.0, cx=320.0, cy=240.0):
    base = stage.look_at((40.0, -30.0, 900.0), (0.0, 0.0, 0.0), width=width, height=height)
    K = np.array([[f, 0.0, cx], [0.0, 1.02 * f, cy], [0.0, 0.0, 1.0]])
    return stage.Camera(K=jnp.asarray(K, jnp.float32), R=base.R, t=base.t, width=width, height=height,
                        dist=jnp.asarray(dist, jnp.float32))


def _points(cam, n=200, seed=0):
    """World points whose projections fill the image (corners included), 600-1200 mm deep."""
    rng = np.random.default_rng(seed)
    fx, fy = float(cam.K[0, 0]), float(cam.K[1, 1])
    xn = rng.uniform(-0.5, 0.5, n) * cam.width / fx
    yn = rng.uniform(-0.5, 0.5, n) * cam.height / fy
    z = rng.uniform(600.0, 1200.0, n)
    xc = np.stack([xn * z, yn * z, z], 1)
    R, t = np.asarray(cam.R, np.float64), np.asarray(cam.t, np.float64)
    return (xc - t) @ R  # X = R^T (X_c - t)


def test_distortion_matches_kornias_opencv_model():
    """Camera.project = kornia's distort_points of the undistorted projection, + 0.5 px (kornia, as OpenCV,
    puts pixel centres at integers), to 2e-3 px over a 640 x 480 image with a 5% barrel lens."""
    torch = pytest.importorskip("torch")
    from kornia.geometry.calibration import distort_points

    cam = _camera()
    X = _points(cam)
    uv, _ = cam.project(jnp.asarray(X))
    K_cv = np.asarray(cam.K, np.float64).copy()
    K_cv[:2, 2] -= 0.5
    xc = X @ np.asarray(cam.R, np.float64).T + np.asarray(cam.t, np.float64)
    ideal = (xc[:, :2] / xc[:, 2:]) @ K_cv[:2, :2].T + K_cv[:2, 2]  # the pinhole's pixels, OpenCV's centres
    ref = distort_points(torch.tensor(ideal), torch.tensor(K_cv), torch.tensor(DIST)).numpy()
    assert np.abs(ref - ideal).max() > 5.0  # the lens moves the corners by pixels: the check is not vacuous
    np.testing.assert_allclose(np.asarray(uv, np.float64) - 0.5, ref, atol=2e-3)


def test_rays_invert_project_through_the_lens():
    """The ray through a point's distorted pixel passes through the point: direction error below 1e-5 rad
    (float32 camera) everywhere in the image."""
    cam = _camera()
    X = _points(cam, seed=1)
    uv, _ = cam.project(jnp.asarray(X, jnp.float32))
    origin, d = cam.rays(uv)
    want = X - np.asarray(origin, np.float64)
    want /= np.linalg.norm(want, axis=1, keepdims=True)
    angle = np.linalg.norm(np.cross(np.asarray(d, np.float64), want), axis=1)  # sin, exact near 0 (arccos is not)
    assert angle.max() < 1e-5


def test_undistort_inverts_distort_and_zero_is_the_identity():
    xy = jnp.asarray(np.random.default_rng(2).uniform(-0.6, 0.6, (500, 2)))
    back = stage.undistort(stage.distort(xy, jnp.asarray(DIST))[0], jnp.asarray(DIST))
    np.testing.assert_allclose(np.asarray(back), np.asarray(xy), atol=1e-9)
    same, ok = stage.distort(xy, jnp.zeros(5, xy.dtype))
    assert np.array_equal(np.asarray(same), np.asarray(xy)) and bool(np.all(ok))


def test_points_past_the_fold_of_a_strong_barrel_leave_the_image():
    """k1 = -0.5 folds r L(r) back at r = 1 / sqrt(1.5): a point at r = 1.2 would land inside the image;
    project sends it to (-1, -1) instead, and keeps points inside the fold."""
    cam = _camera(dist=[-0.5, 0.0, 0.0, 0.0, 0.0], f=300.0)
    xc = np.array([[0.2, 0.1, 1.0], [1.2, 0.0, 1.0]]) * 800.0
    X = (xc - np.asarray(cam.t, np.float64)) @ np.asarray(cam.R, np.float64)
    uv, _ = cam.project(jnp.asarray(X))
    uv = np.asarray(uv)
    assert np.all(uv[0] > 0) and np.array_equal(uv[1], [-1.0, -1.0])


def test_opencv_file_puts_the_top_left_pixel_centre_at_zero(tmp_path):
    """A file's K is OpenCV's: a point OpenCV projects to (0, 0) is the centre of pixel (0, 0), which the
    Camera (continuous coordinates) calls (0.5, 0.5); a centred 256 px camera has cx = 127.5 in the file."""
    cam = stage.look_at((0.0, 0.0, 1000.0), width=256, height=256)
    doc = stage.camera_to_dict(cam)
    assert doc["K"][0][2] == 127.5 and doc["K"][1][2] == 127.5 and "distortion" not in doc
    fx, cx = 700.0, 100.0
    doc.update(K=[[fx, 0, cx], [0, fx, cx], [0, 0, 1]])
    (tmp_path / "c.json").write_text(json.dumps({"convention": "opencv", "units": "mm", "cameras": [doc]}))
    read = stage.load_cameras(tmp_path / "c.json")[0]
    # The camera point OpenCV maps to pixel (0, 0): x / z = (0 - cx) / fx.
    z = 800.0
    xc = np.array([(0 - cx) / fx * z, (0 - cx) / fx * z, z])
    X = (xc - np.asarray(read.t, np.float64)) @ np.asarray(read.R, np.float64)
    uv, _ = read.project(jnp.asarray(X))
    np.testing.assert_allclose(np.asarray(uv), [0.5, 0.5], atol=1e-3)
    # "colmap": K as the Camera holds it (centres at + 0.5); the same numbers read half a pixel apart.
    doc["convention"] = "colmap"
    colmap = stage.camera_from_dict(doc)
    np.testing.assert_allclose(np.asarray(colmap.K)[:2, 2] + 0.5, np.asarray(read.K)[:2, 2])


def test_a_file_round_trip_keeps_k_and_the_distortion(tmp_path):
    cam = _camera()
    stage.save_cameras(tmp_path / "c.json", [cam])
    doc = json.loads((tmp_path / "c.json").read_text())["cameras"][0]
    assert doc["convention"] == "opencv" and doc["K"][0][2] == pytest.approx(319.5)
    assert doc["distortion"] == pytest.approx(DIST.tolist(), rel=1e-6)
    back = stage.load_cameras(tmp_path / "c.json")[0]
    assert np.array_equal(np.asarray(back.K), np.asarray(cam.K))
    assert np.array_equal(np.asarray(back.dist), np.asarray(cam.dist))
    doc["distortion"] = {"k1": -0.2, "p2": 0.001}  # the object form: missing keys are 0
    assert np.allclose(np.asarray(stage.camera_from_dict(doc).dist), [-0.2, 0, 0, 0.001, 0])


@pytest.mark.parametrize(("field", "value", "message"), [
    ("convention", "opengl", r"field 'convention' must be one of \['colmap', 'opencv'\]"),
    ("distortion", [0.1] * 8, r"field 'distortion' must list OpenCV's \[k1, k2, p1, p2\(, k3\)\], got 8"),
    ("distortion", {"k4": 0.1}, r"field 'distortion' has unknown keys \['k4'\]"),
    ("distortion", [0.1, "x", 0, 0], r"field 'distortion' must be numbers"),
    ("dist", [0.1, 0, 0, 0], r"field 'dist' is not read; lens distortion goes in 'distortion'"),
    ("k1", 0.1, r"field 'k1' is not read; lens distortion goes in 'distortion'"),
])
def test_bad_convention_or_distortion_names_the_field(field, value, message):
    doc = {**stage.camera_to_dict(stage.look_at((0.0, 0.0, 1000.0))), field: value}
    with pytest.raises(ValueError, match=r"cam\.json: camera 3: " + message):
        stage.camera_from_dict(doc, "cam.json: camera 3")


def test_an_orthographic_camera_takes_no_distortion():
    doc = {**stage.camera_to_dict(stage.orthographic((0.0, 0.0, 1000.0))), "distortion": [0.1, 0, 0, 0]}
    with pytest.raises(ValueError, match="field 'distortion' must be zero for an orthographic camera"):
        stage.camera_from_dict(doc)
    ortho = stage.orthographic((0.0, 0.0, 1000.0))
    with pytest.raises(ValueError, match="orthographic camera takes no lens distortion"):
        stage.Camera(K=ortho.K, R=ortho.R, t=ortho.t, width=8, height=8, orthographic=True,
                     dist=jnp.asarray([0.1, 0, 0, 0, 0], jnp.float32))


def test_scaling_a_camera_keeps_its_lens():
    """relight.render.scaled_camera changes the pixel count, not the lens: a point lands on the same fraction
    of the image."""
    from relight.render import scaled_camera

    cam = _camera()
    half = scaled_camera(cam, 320)
    X = jnp.asarray(_points(cam, 20, seed=3))
    a, _ = cam.project(X)
    b, _ = half.project(X)
    np.testing.assert_allclose(np.asarray(b) * 2.0, np.asarray(a), atol=2e-3)


def test_mitsuba_export_warns_that_the_lens_is_left_out(tmp_path):
    from relight.export._mitsuba import _check_camera

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _check_camera(stage.look_at((0.0, 0.0, 1000.0)))  # no distortion: silent
    with pytest.warns(UserWarning, match="no lens distortion"):
        _check_camera(_camera())

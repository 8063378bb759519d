import json
import os

import jax
import numpy as np
import pytest

import stage


def test_orthographic_projection_and_rays():
    cam = stage.orthographic((0.0, 0.0, 1000.0), extent_mm=200.0, width=100, height=100)
    pts = np.array([[0.0, 0, 0], [50.0, 20, -30], [-10.0, -40, 80]], np.float32)
    pix, z = cam.project(pts)
    # 0.5 px per mm, image x along world +x, image y along world -y; depth does not matter.
    np.testing.assert_allclose(np.asarray(pix), [[50, 50], [75, 40], [45, 70]], atol=1e-4)
    np.testing.assert_allclose(np.asarray(z), 1000.0 - pts[:, 2], rtol=1e-6)
    origins, d = cam.rays(pix)
    np.testing.assert_allclose(np.asarray(d), np.tile([0, 0, -1.0], (3, 1)), atol=1e-6)
    # Each ray starts on the image plane and passes through its point.
    o = np.asarray(origins)
    np.testing.assert_allclose(o[:, :2], pts[:, :2], atol=1e-3)
    np.testing.assert_allclose(o[:, 2], 1000.0, atol=1e-3)
    np.testing.assert_allclose(np.asarray(cam.view_directions(pts)), np.tile([0, 0, 1.0], (3, 1)), atol=1e-6)


def test_camera_ring_looks_at_the_target():
    cams = stage.camera_ring(8, 1200.0, elevation_mm=100.0, width=64, height=48)
    assert len(cams) == 8
    c = np.stack([np.asarray(k.center, np.float64) for k in cams])
    np.testing.assert_allclose(np.hypot(c[:, 0], c[:, 2]), 1200.0, rtol=1e-5)
    np.testing.assert_allclose(c[:, 1], 100.0, atol=1e-3)
    np.testing.assert_allclose(c[0], [0, 100, 1200], atol=1e-3)  # azimuth 0 is the main camera (+z)
    az = np.degrees(np.arctan2(c[:, 0], c[:, 2])) % 360
    np.testing.assert_allclose(az, np.arange(8) * 45.0, atol=1e-3)
    for k in cams:
        pix, _ = k.project(np.zeros((1, 3), np.float32))
        np.testing.assert_allclose(np.asarray(pix)[0], [32, 24], atol=1e-3)
    arc = stage.camera_ring(3, 1000.0, start_deg=-60, arc_deg=120)
    az = np.degrees([np.arctan2(float(k.center[0]), float(k.center[2])) for k in arc])
    np.testing.assert_allclose(az, [-60, 0, 60], atol=1e-3)
    with pytest.raises(ValueError, match="n >= 1"):
        stage.camera_ring(0, 1000.0)


def test_camera_files_round_trip_atomically(tmp_path):
    cams = stage.camera_ring(3, 900.0) + (stage.orthographic((0.0, 500.0, 0.0), up=(0, 0, -1.0)),)
    path = stage.save_cameras(tmp_path / "cameras.json", cams)
    assert sorted(os.listdir(tmp_path)) == ["cameras.json"]  # no temporary file left behind
    back = stage.load_cameras(path)
    assert [c.orthographic for c in back] == [False, False, False, True]
    pts = np.random.default_rng(0).uniform(-100, 100, (20, 3)).astype(np.float32)
    for a, b in zip(cams, back, strict=True):
        np.testing.assert_allclose(np.asarray(b.project(pts)[0]), np.asarray(a.project(pts)[0]), atol=1e-3)
        assert (a.width, a.height) == (b.width, b.height)
    doc = json.loads(path.read_text())
    assert doc["convention"] == "opencv" and len(doc["cameras"][0]["K"]) == 3
    # Bad files: missing field, non-rotation, not JSON.
    del doc["cameras"][1]["R"]
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="bad.json: camera 1: missing field 'R'"):
        stage.load_cameras(tmp_path / "bad.json")
    doc = json.loads(path.read_text())
    doc["cameras"][0]["R"] = (2 * np.eye(3)).tolist()
    (tmp_path / "scaled.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="camera 0: field 'R' is not a rotation"):
        stage.load_cameras(tmp_path / "scaled.json")
    (tmp_path / "junk.json").write_text("{not json")
    with pytest.raises(ValueError, match="junk.json: not valid JSON"):
        stage.load_cameras(tmp_path / "junk.json")


def test_orthographic_camera_under_jit():
    cam = stage.orthographic((0.0, 0.0, 1000.0))
    p = np.array([[10.0, 5.0, 0.0]], np.float32)
    f = jax.jit(lambda c, x: c.project(x)[0])
    np.testing.assert_allclose(np.asarray(f(cam, p)), np.asarray(cam.project(p)[0]), rtol=1e-6)


def test_camera_dicts_are_the_one_schema(tmp_path):
    """camera_to_dict is what camera files, capture folders and map sets store;
    load_cameras reads every form earlier versions wrote: save_cameras's object
    (with or without per-camera convention/units) and a bare list (a capture
    folder's cameras.json, as the CLI wrote it)."""
    cams = (stage.look_at((100.0, 50.0, 900.0), width=64, height=48),
            stage.orthographic((0.0, 500.0, 0.0), up=(0, 0, -1.0), width=32, height=32))
    d = stage.camera_to_dict(cams[0], "front")
    assert d["name"] == "front" and d["model"] == "pinhole" and d["convention"] == "opencv" and d["units"] == "mm"
    assert json.loads(json.dumps(d)) == d  # JSON-ready as it is
    assert "name" not in stage.camera_to_dict(cams[1]) and stage.camera_to_dict(cams[1])["model"] == "orthographic"
    pts = np.random.default_rng(1).uniform(-50, 50, (10, 3)).astype(np.float32)

    def same(a, b):
        assert (a.width, a.height, a.orthographic) == (b.width, b.height, b.orthographic)
        np.testing.assert_allclose(np.asarray(b.project(pts)[0]), np.asarray(a.project(pts)[0]), atol=1e-4)

    for a in cams:
        same(a, stage.camera_from_dict(stage.camera_to_dict(a)))
    # A bare list (capture folders; the CLI's old camera_to_json, field for field).
    listed = [stage.camera_to_dict(c, f"cam{i:03d}") for i, c in enumerate(cams)]
    (tmp_path / "list.json").write_text(json.dumps(listed))
    # save_cameras's object as written before the per-camera convention/units keys.
    old = {"convention": "opencv", "units": "mm", "cameras": [
        {k: v for k, v in stage.camera_to_dict(c, "x").items() if k not in ("convention", "units")} for c in cams]}
    (tmp_path / "old.json").write_text(json.dumps(old))
    for name in ("list.json", "old.json"):
        back = stage.load_cameras(tmp_path / name)
        assert len(back) == 2
        for a, b in zip(cams, back, strict=True):
            same(a, b)


def test_camera_dict_errors_name_the_file_camera_and_field(tmp_path):
    good = stage.camera_to_dict(stage.look_at((0.0, 0.0, 1000.0)))
    cases = [
        ({**good, "width": 0}, r"x\.json: camera 0: field 'width' must be a positive integer"),
        ({**good, "height": 2.5}, r"camera 0: field 'height' must be a positive integer"),
        ({**good, "model": "fisheye"}, r"camera 0: field 'model' must be 'pinhole' or 'orthographic'"),
        ({**good, "units": "cm"}, r"camera 0: field 'units' must be 'mm', got 'cm'"),
        ({**good, "convention": "opengl"},
         r"camera 0: field 'convention' must be one of \['colmap', 'opencv'\].*got 'opengl'"),
        ({**good, "t": [0.0, 1.0]}, r"camera 0: field 't' must be finite with shape \(3,\)"),
        ({**good, "K": "eye"}, r"camera 0: malformed field"),
        ("not a camera", r"camera 0: expected a JSON object"),
    ]
    for doc, pattern in cases:
        (tmp_path / "x.json").write_text(json.dumps([doc]))
        with pytest.raises(ValueError, match=pattern):
            stage.load_cameras(tmp_path / "x.json")
    (tmp_path / "x.json").write_text(json.dumps({"units": "inch", "cameras": [good]}))
    with pytest.raises(ValueError, match=r"x\.json: field 'units' must be 'mm'"):
        stage.load_cameras(tmp_path / "x.json")
    for doc in ([], {"cameras": []}, 3):
        (tmp_path / "x.json").write_text(json.dumps(doc))
        with pytest.raises(ValueError, match=r"x\.json: expected"):
            stage.load_cameras(tmp_path / "x.json")
    with pytest.raises(FileNotFoundError, match="absent.json"):
        stage.load_cameras(tmp_path / "absent.json")


def test_projection_accepts_float64_points_under_strict_promotion():
    """A float32 camera and float64 points (or pixels) meet in the wider dtype,
    cast explicitly, so strict dtype promotion (tests/conftest.py) is satisfied."""
    cam = stage.look_at((0.0, 0.0, 1000.0), width=100, height=100)
    pts = np.array([[10.0, -5.0, 20.0]])
    with jax.numpy_dtype_promotion("strict"):
        pix, z = cam.project(pts)
        origin, d = cam.rays(np.asarray(pix))
    assert pix.dtype == z.dtype == d.dtype == jax.numpy.float64
    d = np.asarray(d)
    along = np.asarray(z) / (d @ np.asarray(cam.forward, np.float64))  # depth is measured along the optical axis
    np.testing.assert_allclose(np.asarray(origin) + along[:, None] * d, pts, rtol=1e-5)

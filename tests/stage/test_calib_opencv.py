"""stage.read_opencv_calibration against OpenCV's ``projectPoints`` formula (calib3d's pinhole model with
Brown's distortion, and ``Rodrigues``), written here in numpy from the documentation: FileStorage YAML and JSON
files, one camera or several, project known points where OpenCV would put them plus the half pixel between
OpenCV's pixel centres and the Camera's (to 1e-3 px); every refusal names the file and the field.

The writers here (``write_opencv_yaml`` / ``write_opencv_json``) are also the fixtures of
tests/stage/test_calib_metashape.py's cross-format test and tests/relight/test_cli_cameras.py."""

import json

import numpy as np
import pytest

import stage

PX_TOL = 1e-3  # Camera.project stores K, R, t in float32 (~1e-4 px here); OpenCV's formula runs in float64


def _matrix_yaml(name, a, indent="   "):
    """One ``!!opencv-matrix`` node as cv::FileStorage writes it: data wrapped over several lines."""
    a = np.atleast_2d(np.asarray(a, np.float64))
    items = [repr(float(v)) for v in a.reshape(-1)]
    rows = [", ".join(items[k:k + 4]) for k in range(0, len(items), 4)]
    data = (",\n" + indent + "    ").join(rows)
    return (f"{name}: !!opencv-matrix\n{indent}rows: {a.shape[0]}\n{indent}cols: {a.shape[1]}\n{indent}dt: d\n"
            f"{indent}data: [ {data} ]\n")


def write_opencv_yaml(path, cameras):
    """A FileStorage YAML file: ``cameras`` = {name: fields} with fields K, dist, R or rvec, t, width, height
    (OpenCV's pixel convention); one camera at the top level (OpenCV's calibration sample's keys), several as a
    mapping of names to cameras."""
    def body(cam, indent):
        pad = indent + "   "
        out = f"{indent}image_width: {cam['width']}\n{indent}image_height: {cam['height']}\n"
        out += indent + _matrix_yaml("camera_matrix", cam["K"], pad)
        if "dist" in cam:
            out += indent + _matrix_yaml("distortion_coefficients", cam["dist"], pad)
        if "rvec" in cam:
            out += indent + _matrix_yaml("rvec", np.reshape(cam["rvec"], (3, 1)), pad)
        else:
            out += indent + _matrix_yaml("R", cam["R"], pad)
        out += indent + _matrix_yaml("T", np.reshape(cam["t"], (3, 1)), pad)
        return out

    text = '%YAML:1.0\n---\ncalibration_time: "Tue 01 Dec 2026 10:00:00"\nnframes: 25\n'
    if len(cameras) == 1:
        text += body(next(iter(cameras.values())), "") + "avg_reprojection_error: 0.21\n"
    else:
        for name, cam in cameras.items():
            text += f"{name}:\n" + body(cam, "   ")
    path.write_text(text)
    return path


def write_opencv_json(path, cameras, layout="list"):
    """A JSON file of the same fields: a top-level "cameras" list with names ("list") or a mapping name ->
    camera ("mapping")."""
    def fields(cam):
        out = {"K": np.asarray(cam["K"]).tolist(), "t": list(map(float, cam["t"])), "width": cam["width"],
               "height": cam["height"]}
        out.update({k: np.asarray(cam[k]).tolist() for k in ("dist", "R", "rvec") if k in cam})
        return out

    doc = ({"cameras": [{"name": n, **fields(c)} for n, c in cameras.items()]} if layout == "list"
           else {n: fields(c) for n, c in cameras.items()})
    path.write_text(json.dumps(doc, indent=1))
    return path


def rotate_rodrigues(rvec, v):
    """v rotated about the axis rvec / |rvec| by |rvec| radians (Rodrigues' rotation formula on vectors)."""
    theta = np.linalg.norm(rvec)
    k = np.asarray(rvec) / theta
    return (v * np.cos(theta) + np.cross(k, v) * np.sin(theta)
            + np.outer(v @ k, k) * (1 - np.cos(theta)))


def opencv_project(cam, points):
    """cv2.projectPoints (calib3d's pinhole model): X_c = R X + t, x' = X_c / Z_c, Brown's distortion with
    (k1, k2, p1, p2[, k3]), u = fx x'' + cx, in OpenCV's pixels (top-left pixel centre at (0, 0))."""
    xc = (rotate_rodrigues(cam["rvec"], points) if "rvec" in cam else points @ np.asarray(cam["R"]).T)
    xc = xc + np.asarray(cam["t"])
    x, y = xc[:, 0] / xc[:, 2], xc[:, 1] / xc[:, 2]
    k1, k2, p1, p2, k3 = (list(cam.get("dist", [])) + [0.0] * 5)[:5]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    K = np.asarray(cam["K"])
    return np.stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=-1)


def opencv_cameras():
    """Two OpenCV calibrations (units: cm): one with a Rodrigues vector and five coefficients, one with R and
    four."""
    a = {"K": [[900.0, 0.0, 330.25], [0.0, 880.0, 241.5], [0.0, 0.0, 1.0]],
         "dist": [-0.12, 0.05, 0.0012, -0.0008, 0.01], "rvec": [0.1, -2.9, 0.05], "t": [1.5, -2.0, 200.0],
         "width": 640, "height": 480}
    R = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])  # looking along -x from +x
    b = {"K": [[1200.0, 0.0, 511.5], [0.0, 1200.0, 383.5], [0.0, 0.0, 1.0]], "dist": [0.03, -0.01, 0.0, 0.0005],
         "R": R.tolist(), "t": (-R @ np.array([180.0, 3.0, -4.0])).tolist(), "width": 1024, "height": 768}
    return {"left": a, "right": b}


def check_projections(cams, truth, mm_per_unit, rng_seed=0):
    """Each camera projects points in view (a 20-unit cube at the origin) as OpenCV does, + 0.5 px."""
    X = np.random.default_rng(rng_seed).uniform(-10.0, 10.0, size=(64, 3))
    for name, fields in truth.items():
        pix, _ = cams[name].project(X * mm_per_unit)
        np.testing.assert_allclose(np.asarray(pix), opencv_project(fields, X) + 0.5, atol=PX_TOL, rtol=0)
        assert (cams[name].width, cams[name].height) == (fields["width"], fields["height"])


def test_one_camera_filestorage_yaml(tmp_path):
    truth = {"left": opencv_cameras()["left"]}
    cams = stage.read_opencv_calibration(write_opencv_yaml(tmp_path / "cam03.yml", truth), "cm")
    assert list(cams) == ["cam03"]  # one camera: the file's stem
    check_projections({"left": cams["cam03"]}, truth, 10.0)


def test_several_cameras_filestorage_yaml(tmp_path):
    truth = opencv_cameras()
    cams = stage.read_opencv_calibration(write_opencv_yaml(tmp_path / "rig.yml", truth), 10.0)
    assert list(cams) == ["left", "right"]
    check_projections(cams, truth, 10.0)


@pytest.mark.parametrize("layout", ["list", "mapping"])
def test_json(tmp_path, layout):
    truth = opencv_cameras()
    cams = stage.read_opencv_calibration(write_opencv_json(tmp_path / "rig.json", truth, layout), "cm")
    assert list(cams) == ["left", "right"]
    check_projections(cams, truth, 10.0)


def test_the_principal_point_gains_half_a_pixel(tmp_path):
    truth = {"c": opencv_cameras()["right"]}
    cam = stage.read_opencv_calibration(write_opencv_json(tmp_path / "c.json", truth), 1.0)["c"]
    np.testing.assert_allclose(np.asarray(cam.K)[:2, 2], [512.0, 384.0])


def test_yaml_sequence_of_cameras_and_filestorage_json(tmp_path):
    """A block sequence under ``cameras`` (``- name: ...`` items, comments) and FileStorage's own JSON matrices."""
    cam = opencv_cameras()["left"]
    K, d = (", ".join(repr(float(v)) for v in np.ravel(cam[k])) for k in ("K", "dist"))
    text = ("%YAML:1.0\n---\n# two cameras\ncameras:  # a block sequence\n"
            f"   - name: a  # the left one\n     image_width: 640\n     image_height: 480\n"
            f"     K: !!opencv-matrix\n        rows: 3\n        cols: 3\n        dt: d\n        data: [ {K} ]\n"
            f"     D: [ {d} ]\n     rvec: [ 0.1, -2.9, 0.05 ]\n     tvec: [ 1.5, -2.0, 200.0 ]\n"
            "   -\n      name: b\n      image_width: 640\n      image_height: 480\n"
            f"      K: [ {K} ]\n      rvec: [ 0.1, -2.9, 0.05 ]\n      tvec: [ 1.5, -2.0, 200.0 ]\n")
    (tmp_path / "seq.yaml").write_text(text)
    cams = stage.read_opencv_calibration(tmp_path / "seq.yaml", "cm")
    assert list(cams) == ["a", "b"]
    check_projections({"a": cams["a"]}, {"a": cam}, 10.0)
    check_projections({"b": cams["b"]}, {"b": {k: v for k, v in cam.items() if k != "dist"}}, 10.0)
    fs = {"camera_matrix": {"type_id": "opencv-matrix", "rows": 3, "cols": 3, "dt": "d",
                            "data": np.ravel(cam["K"]).tolist()},
          "distortion_coefficients": {"type_id": "opencv-matrix", "rows": 5, "cols": 1, "dt": "d",
                                      "data": cam["dist"]},
          "rvec": cam["rvec"], "tvec": cam["t"], "image_width": 640, "image_height": 480}
    (tmp_path / "fs.json").write_text(json.dumps(fs))
    check_projections({"left": stage.read_opencv_calibration(tmp_path / "fs.json", "cm")["fs"]}, {"left": cam}, 10.0)


@pytest.mark.parametrize("n", [8, 12, 14])
def test_long_distortion_models_are_refused(tmp_path, n):
    truth = {"c": dict(opencv_cameras()["left"], dist=[0.01] * n)}
    with pytest.raises(ValueError, match=rf"c.yml: camera 'c': field 'distortion' .*got {n}"):
        stage.read_opencv_calibration(write_opencv_yaml(tmp_path / "c.yml", truth), 1.0)


@pytest.mark.parametrize("edit, match", [
    (lambda c: c.pop("width"), r"camera 'c': missing field 'image_width' / 'width'"),
    (lambda c: c.pop("K"), r"camera 'c': missing field 'camera_matrix' / 'K' / 'cameraMatrix'"),
    (lambda c: c.pop("t"), r"camera 'c': missing field 'T' / 't' / 'tvec'"),
    (lambda c: c.pop("rvec"), r"camera 'c': missing field 'R' \(3x3\) / 'rvec'"),
    (lambda c: c.update(R=np.eye(3).tolist()), r"camera 'c': both fields 'R' \(3x3\) / 'rvec'"),
    (lambda c: c.update(camera_matrix=c["K"]), r"camera 'c': fields \['camera_matrix', 'K'\] are the same field"),
    (lambda c: c.update(K=[[900.0, 0.0, 330.0], [0.0, 880.0, 240.0]]), r"camera 'c': field 'K' must hold 9"),
    (lambda c: c.update(K=[[900.0, 0.0, 330.0], [5.0, 880.0, 240.0], [0, 0, 1]]),
     r"camera 'c': field 'K' must be upper"),
    (lambda c: c.update(t=["a", "b", "c"]), r"camera 'c': field 't' must be numbers"),
    (lambda c: c.update(rvec=[0.0, float("nan"), 0.0]), r"camera 'c': field 'rvec'"),
    (lambda c: c.update(height=0), r"camera 'c': field 'height' must be a positive integer"),
])
def test_bad_fields_are_refused_naming_file_camera_and_field(tmp_path, edit, match):
    cam = opencv_cameras()["left"]
    edit(cam)
    path = tmp_path / "c.json"
    path.write_text(json.dumps({"cameras": [{"name": "c", **cam}]}))
    with pytest.raises(ValueError, match=rf"c.json: {match}"):
        stage.read_opencv_calibration(path, 1.0)


@pytest.mark.parametrize("text, match", [
    ("%YAML:1.0\nK: [1, 2\n", r"bad.yml:2: unterminated flow sequence"),
    ("%YAML:1.0\na: 1\n  b: 2\n", r"bad.yml:3: unexpected indentation"),
    ("%YAML:1.0\na: 1\n\tb: 2\n", r"bad.yml:3: tab in the indentation"),
    ("%YAML:1.0\na: 1\na: 2\n", r"bad.yml:3: key 'a' appears twice"),
    ("%YAML:1.0\na: {b: 1}\n", r"bad.yml:2: flow mappings"),
    ("%YAML:1.0\nK: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [1, 2]\n",
     r"bad.yml:2: 'K': !!opencv-matrix declares shape \(3, 3\) but holds 2 numbers"),
    ("%YAML:1.0\nK: !!opencv-matrix\n   rows: 3\n   dt: d\n   data: [1, 2]\n",
     r"bad.yml:2: 'K': .*missing field 'cols'"),
    ("%YAML:1.0\nK: !!binary abc\n", r"bad.yml:2: 'K': unsupported tag !!binary"),
    ("%YAML:1.0\njust text\n", r"bad.yml:2: expected 'key: value'"),
    ("%YAML:1.0\n", r"bad.yml: empty calibration file"),
    ("%YAML:1.0\nnframes: 3\n", r"bad.yml: no camera found"),
    ('<?xml version="1.0"?>\n<opencv_storage/>\n', r"bad.yml: OpenCV's XML FileStorage is not supported"),
    ('{"K": [1, 2, 3', r"bad.yml: not valid JSON"),
])
def test_malformed_files_name_the_file_and_line(tmp_path, text, match):
    (tmp_path / "bad.yml").write_text(text)
    with pytest.raises(ValueError, match=match):
        stage.read_opencv_calibration(tmp_path / "bad.yml", 1.0)


def test_a_missing_file_and_bad_units(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothing.yml: no such OpenCV calibration file"):
        stage.read_opencv_calibration(tmp_path / "nothing.yml", 1.0)
    path = write_opencv_json(tmp_path / "c.json", opencv_cameras())
    for units in (0.0, -10.0, float("inf"), "inch"):
        with pytest.raises(ValueError, match="mm_per_unit"):
            stage.read_opencv_calibration(path, units)

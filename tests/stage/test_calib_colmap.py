"""stage.read_colmap against COLMAP's own projection formulas (src/colmap/sensor/models.h), written here in
numpy from the documentation: a model's images project known points where COLMAP would put them (to 1e-3 px);
the text and binary forms of one model give identical cameras; every refusal names the file and the field.

The writers here (``write_colmap_text`` / ``write_colmap_binary``) are also the fixtures of
tests/stage/test_calib_metashape.py's cross-format test and tests/relight/test_cli_cameras.py."""

import math
import struct

import numpy as np
import pytest

import stage

# Camera.project stores K, R, t in float32: at 640 px and 1 m, its error is ~1e-4 px; the formats' own
# formulas run in float64.
PX_TOL = 1e-3

MODEL_IDS = {"SIMPLE_PINHOLE": 0, "PINHOLE": 1, "SIMPLE_RADIAL": 2, "RADIAL": 3, "OPENCV": 4,
             "OPENCV_FISHEYE": 5, "FULL_OPENCV": 6}


def write_colmap_text(folder, cameras, images):
    """cameras.txt and images.txt: ``cameras`` = [(id, model, width, height, params)], ``images`` =
    [(id, qvec, tvec, camera_id, name, points2d [N, 3] or None)], COLMAP's layout with its header comments."""
    folder.mkdir(parents=True, exist_ok=True)
    lines = ["# Camera list with one line of data per camera:",
             "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]", f"# Number of cameras: {len(cameras)}"]
    lines += [" ".join([str(i), model, str(w), str(h)] + [repr(float(p)) for p in params])
              for i, model, w, h, params in cameras]
    (folder / "cameras.txt").write_text("\n".join(lines) + "\n")
    lines = ["# Image list with two lines of data per image:",
             "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
             "#   POINTS2D[] as (X, Y, POINT3D_ID)", f"# Number of images: {len(images)}, mean observations: 0"]
    for i, q, t, cam, name, pts in images:
        lines.append(" ".join([str(i)] + [repr(float(v)) for v in (*q, *t)] + [str(cam), name]))
        lines.append("" if pts is None else " ".join(f"{x!r} {y!r} {int(p)}" for x, y, p in pts))
    (folder / "images.txt").write_text("\n".join(lines) + "\n")


def write_colmap_binary(folder, cameras, images):
    """cameras.bin and images.bin of the same records, in read_write_model.py's little-endian layout."""
    folder.mkdir(parents=True, exist_ok=True)
    data = struct.pack("<Q", len(cameras))
    for i, model, w, h, params in cameras:
        data += struct.pack("<iiQQ", i, MODEL_IDS[model], w, h) + struct.pack(f"<{len(params)}d", *params)
    (folder / "cameras.bin").write_bytes(data)
    data = struct.pack("<Q", len(images))
    for i, q, t, cam, name, pts in images:
        pts = np.zeros((0, 3)) if pts is None else np.asarray(pts)
        data += struct.pack("<i4d3di", i, *q, *t, cam) + name.encode() + b"\0" + struct.pack("<Q", len(pts))
        data += b"".join(struct.pack("<ddq", x, y, int(p)) for x, y, p in pts)
    (folder / "images.bin").write_bytes(data)


def quat_rotate(q, v):
    """v rotated by the Hamilton quaternion q = (w, x, y, z): the vector part of q (0, v) q^* (normalised q)."""
    w, x, y, z = np.asarray(q, np.float64) / np.linalg.norm(q)
    u = np.array([x, y, z])
    return v + 2 * w * np.cross(u, v) + 2 * np.cross(u, np.cross(u, v))


def colmap_project(model, params, q, t, points):
    """COLMAP's ImgFromCam for the five pinhole models (models.h): camera = R(q) X + t, (u, v) = (x/z, y/z),
    the model's distortion, then f * u + c."""
    xc = quat_rotate(q, points) + np.asarray(t)
    u, v = xc[:, 0] / xc[:, 2], xc[:, 1] / xc[:, 2]
    p = list(params)
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        fx = fy = p[0]
        cx, cy, extra = p[1], p[2], p[3:]
    else:
        fx, fy, cx, cy, extra = p[0], p[1], p[2], p[3], p[4:]
    k1, k2, p1, p2 = (extra + [0.0] * 4)[:4]
    r2 = u * u + v * v
    radial = k1 * r2 + k2 * r2 * r2
    du = u * radial + 2 * p1 * u * v + p2 * (r2 + 2 * u * u)
    dv = v * radial + 2 * p2 * u * v + p1 * (r2 + 2 * v * v)
    return np.stack([fx * (u + du) + cx, fy * (v + dv) + cy], axis=-1)


def points_in_view(rng, n=64):
    """Points (in the model's units, metres here) in a 0.3-unit cube at the origin: in front of every camera of
    ``two_camera_model`` (about 2 units away, looking at the origin)."""
    return rng.uniform(-0.15, 0.15, size=(n, 3))


def look_at_pose(eye):
    """A world-to-camera (quaternion, t) looking from ``eye`` at the origin, y down."""
    fwd = -np.asarray(eye, np.float64) / np.linalg.norm(eye)
    right = np.cross(fwd, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    R = np.stack([right, np.cross(fwd, right), fwd])
    w = math.sqrt(max(0.0, 1 + np.trace(R))) / 2
    q = np.array([w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w)])
    return q, -R @ np.asarray(eye, np.float64)


PARAMS = {
    "SIMPLE_PINHOLE": [820.0, 320.5, 239.25],
    "PINHOLE": [820.0, 790.0, 321.0, 238.0],
    "SIMPLE_RADIAL": [820.0, 320.5, 239.25, -0.08],
    "RADIAL": [820.0, 320.5, 239.25, -0.08, 0.02],
    "OPENCV": [820.0, 790.0, 321.0, 238.0, -0.08, 0.02, 0.001, -0.0015],
}


def two_camera_model(model="OPENCV"):
    """Two cameras of ``model`` (640 x 480) and three images, one with 2D points, in metres."""
    cameras = [(1, model, 640, 480, PARAMS[model]), (7, "PINHOLE", 640, 480, PARAMS["PINHOLE"])]
    images = []
    for k, (eye, cam) in enumerate((((0.3, 0.2, 2.0), 1), ((-1.5, 0.4, 1.4), 7), ((1.8, -0.3, -0.9), 1))):
        q, t = look_at_pose(eye)
        pts = np.array([[10.5, 20.25, 3], [11.0, 21.0, -1]]) if k == 0 else None
        images.append((k + 1, q * (-1.0 if k == 2 else 1.0), t, cam, f"cam{k:03d}.png", pts))
    return cameras, images


@pytest.mark.parametrize("model", list(PARAMS))
def test_each_model_projects_as_colmap_does(tmp_path, model):
    cameras, images = two_camera_model(model)
    write_colmap_text(tmp_path, cameras, images)
    cams = stage.read_colmap(tmp_path, mm_per_unit=1000.0)  # the model is in metres
    assert list(cams) == ["cam000.png", "cam001.png", "cam002.png"]
    X = points_in_view(np.random.default_rng(0))
    by_id = {c[0]: c for c in cameras}
    for (_, q, t, cam_id, _name, _), cam in zip(images, cams.values(), strict=True):
        _, mdl, w, h, params = by_id[cam_id]
        expected = colmap_project(mdl, params, q, t, X)
        pix, depth = cam.project(X * 1000.0)
        assert (cam.width, cam.height) == (w, h)
        np.testing.assert_allclose(np.asarray(pix), expected, atol=PX_TOL, rtol=0)
        assert np.all(np.asarray(depth) > 0)


def test_text_and_binary_give_identical_cameras(tmp_path):
    cameras, images = two_camera_model()
    write_colmap_text(tmp_path / "txt", cameras, images)
    write_colmap_binary(tmp_path / "bin", cameras, images)
    a, b = stage.read_colmap(tmp_path / "txt", "m"), stage.read_colmap(tmp_path / "bin", "m")
    assert list(a) == list(b)
    for name in a:
        for field in ("K", "R", "t", "dist"):
            np.testing.assert_array_equal(np.asarray(getattr(a[name], field)), np.asarray(getattr(b[name], field)))
        assert (a[name].width, a[name].height) == (b[name].width, b[name].height)


def test_text_is_preferred_when_a_folder_holds_both(tmp_path):
    cameras, images = two_camera_model()
    write_colmap_text(tmp_path, cameras, images)
    write_colmap_binary(tmp_path, cameras, images[:1])
    assert len(stage.read_colmap(tmp_path, 1.0)) == 3


def test_units_scale_the_translation_only(tmp_path):
    cameras, images = two_camera_model()
    write_colmap_text(tmp_path, cameras, images)
    m, mm = stage.read_colmap(tmp_path, "m"), stage.read_colmap(tmp_path, 1.0)
    cm = stage.read_colmap(tmp_path, "cm")
    for name in m:
        np.testing.assert_allclose(np.asarray(m[name].t), 1000 * np.asarray(mm[name].t), rtol=1e-6)
        np.testing.assert_allclose(np.asarray(cm[name].t), 10 * np.asarray(mm[name].t), rtol=1e-6)
        np.testing.assert_array_equal(np.asarray(m[name].K), np.asarray(mm[name].K))


def test_an_image_without_points_keeps_its_empty_line(tmp_path):
    """The line after an image line is its 2D points, even when empty: the next image is not swallowed."""
    cameras, images = two_camera_model()
    write_colmap_text(tmp_path, cameras, images)
    text = (tmp_path / "images.txt").read_text()
    assert "\n\n" in text  # images 2 and 3 have empty POINTS2D lines
    assert list(stage.read_colmap(tmp_path, 1.0)) == ["cam000.png", "cam001.png", "cam002.png"]


@pytest.mark.parametrize("units", [0, -1.0, float("nan"), float("inf"), "furlong", True])
def test_bad_units_are_refused(tmp_path, units):
    cameras, images = two_camera_model()
    write_colmap_text(tmp_path, cameras, images)
    with pytest.raises(ValueError, match="mm_per_unit"):
        stage.read_colmap(tmp_path, units)


@pytest.mark.parametrize("binary", [False, True])
@pytest.mark.parametrize("model", ["OPENCV_FISHEYE", "FULL_OPENCV"])
def test_other_models_are_refused_naming_file_camera_and_model(tmp_path, binary, model):
    cameras, images = two_camera_model()
    n = {"OPENCV_FISHEYE": 8, "FULL_OPENCV": 12}[model]
    cameras[1] = (7, model, 640, 480, [800.0, 800.0, 320.0, 240.0] + [0.0] * (n - 4))
    (write_colmap_binary if binary else write_colmap_text)(tmp_path, cameras, images)
    name = "cameras.bin" if binary else "cameras.txt"
    with pytest.raises(ValueError, match=rf"{name}: camera 7: model {model} is not supported"):
        stage.read_colmap(tmp_path, 1.0)


def test_a_missing_folder_or_model_is_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere"):
        stage.read_colmap(tmp_path / "nowhere", 1.0)
    (tmp_path / "cameras.txt").write_text("")
    with pytest.raises(FileNotFoundError, match=r"no COLMAP model here .*found cameras.txt"):
        stage.read_colmap(tmp_path, 1.0)


def test_a_file_given_for_the_folder_is_refused(tmp_path):
    cameras, images = two_camera_model()
    write_colmap_text(tmp_path, cameras, images)
    with pytest.raises(ValueError, match="expected a COLMAP model folder"):
        stage.read_colmap(tmp_path / "cameras.txt", 1.0)


@pytest.mark.parametrize("edit, match", [
    (lambda c, i: (c, [(*i[0][:3], 99, *i[0][4:])] + i[1:]), r"images.txt: image 'cam000.png': field 'CAMERA_ID'"),
    (lambda c, i: ([(1, "OPENCV", 640, 480, PARAMS["OPENCV"][:6])] + c[1:], i),
     r"cameras.txt: camera 1: field 'PARAMS': model OPENCV takes 8 parameters, got 6"),
    (lambda c, i: (c, i + [i[0]]), r"image 'cam000.png' is listed twice"),
    (lambda c, i: (c, [(1, (0.0, 0.0, 0.0, 0.0), *i[0][2:])] + i[1:]), r"image 'cam000.png': field 'QW QX QY QZ'"),
    (lambda c, i: ([(1, "OPENCV", 0, 480, PARAMS["OPENCV"])] + c[1:], i), r"cameras.txt: camera 1 .*'width'"),
    (lambda c, i: ([(1, "PINHOLE", 640, 480, [-5.0, 800.0, 320.0, 240.0])] + c[1:], i),
     r"cameras.txt: camera 1 .*field 'K' needs positive focal lengths"),
])
def test_bad_records_are_refused_naming_the_file_and_field(tmp_path, edit, match):
    cameras, images = edit(*two_camera_model())
    write_colmap_text(tmp_path, cameras, images)
    with pytest.raises(ValueError, match=match):
        stage.read_colmap(tmp_path, 1.0)


@pytest.mark.parametrize("which, text, match", [
    ("cameras.txt", "1 PINHOLE 640 480 800 800 320\n", r"cameras.txt: camera 1: field 'PARAMS'"),
    ("cameras.txt", "1 PINHOLE 640\n", r"cameras.txt:1: expected CAMERA_ID MODEL WIDTH HEIGHT"),
    ("cameras.txt", "1 PINHOLE 640 480 800 eight 320 240\n", r"cameras.txt:1: field 'PARAMS'"),
    ("images.txt", "1 1 0 0 0 0 0 1 1\n\n", r"images.txt:1: expected IMAGE_ID QW"),
    ("images.txt", "1 1 0 0 zero 0 0 1 1 a.png\n\n", r"images.txt:1: field 'QW QX QY QZ TX TY TZ'"),
    ("images.txt", "# nothing\n", r"images.txt: no images"),
])
def test_malformed_text_lines_name_the_file_and_line(tmp_path, which, text, match):
    cameras, images = two_camera_model()
    write_colmap_text(tmp_path, cameras, images)
    (tmp_path / which).write_text(text)
    with pytest.raises(ValueError, match=match):
        stage.read_colmap(tmp_path, 1.0)


@pytest.mark.parametrize("which", ["cameras.bin", "images.bin"])
def test_truncated_or_padded_binary_files_are_refused(tmp_path, which):
    cameras, images = two_camera_model()
    write_colmap_binary(tmp_path, cameras, images)
    data = (tmp_path / which).read_bytes()
    (tmp_path / which).write_bytes(data[:-5])
    with pytest.raises(ValueError, match=rf"{which}: truncated at byte \d+ reading"):
        stage.read_colmap(tmp_path, 1.0)
    (tmp_path / which).write_bytes(data + b"\0\0")
    with pytest.raises(ValueError, match=rf"{which}: 2 bytes after the last record"):
        stage.read_colmap(tmp_path, 1.0)


def test_a_binary_count_beyond_the_file_is_refused_before_reading(tmp_path):
    cameras, images = two_camera_model()
    write_colmap_binary(tmp_path, cameras, images)
    data = (tmp_path / "images.bin").read_bytes()
    (tmp_path / "images.bin").write_bytes(struct.pack("<Q", 2**40) + data[8:])
    with pytest.raises(ValueError, match=r"images.bin: declares 1099511627776 images"):
        stage.read_colmap(tmp_path, 1.0)

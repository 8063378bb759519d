"""The stage's boundary refuses what would poison the physics later: cameras
that cannot project (zero focal length, a matrix that is not a rotation, an
image too large to allocate), meshes whose coordinates are NaN, Inf or so large
their squares overflow float32, NaN UVs, and rigs whose lights are all dark
(or negative, NaN, beyond float32). Each error is a ValueError naming the file
or the argument and what is wrong."""

import json

import numpy as np
import pytest

import stage
from stage._camera import MAX_CAMERA_PIXELS
from stage._mesh import MAX_COORDINATE_MM


def _camera_file(tmp_path, **edits):
    doc = {**stage.camera_to_dict(stage.look_at((0.0, 0.0, 500.0), width=8, height=6)), **edits}
    path = tmp_path / "cameras.json"
    path.write_text(json.dumps([doc]))
    return path


def test_cameras_json_refuses_cameras_that_cannot_project(tmp_path):
    K = np.asarray(stage.camera_to_dict(stage.look_at((0.0, 0.0, 500.0)))["K"])
    zero_f, skewed_row = K.copy(), K.copy()
    zero_f[0, 0] = 0.0
    skewed_row[2, 2] = 2.0
    cases = [({"K": zero_f.tolist()}, r"field 'K' needs positive focal lengths, got fx = 0\.0"),
             ({"K": skewed_row.tolist()}, r"field 'K' must be upper triangular with K\[2\] = \[0, 0, 1\]"),
             ({"R": np.zeros((3, 3)).tolist()}, r"field 'R' is not a rotation matrix"),
             ({"R": (-np.eye(3)).tolist()}, r"field 'R' is not a rotation matrix"),  # det -1: a reflection
             ({"width": 100000, "height": 100000}, rf"image size 100000x100000 is above the limit of "
                                                   rf"{MAX_CAMERA_PIXELS} pixels"),
             ({"width": 1e300}, r"field 'width' must be a positive integer"),
             ({"height": float("nan")}, r"field 'height' must be a positive integer")]
    for edit, pattern in cases:
        with pytest.raises(ValueError, match=r"cameras\.json: camera 0: " + pattern):
            stage.load_cameras(_camera_file(tmp_path, **edit))
    assert stage.load_cameras(_camera_file(tmp_path))[0].width == 8  # the unedited file still reads


def test_camera_construction_refuses_zero_focal_length_and_huge_images():
    good = stage.look_at((0.0, 0.0, 500.0), width=8, height=6)
    with pytest.raises(ValueError, match=r"argument 'K': focal lengths fx = 0\.0"):
        stage.Camera(K=good.K.at[0, 0].set(0.0), R=good.R, t=good.t, width=8, height=6)
    with pytest.raises(ValueError, match=r"100000x100000 is above the limit"):
        stage.Camera(K=good.K, R=good.R, t=good.t, width=100000, height=100000)
    # Inside jit the fields are tracers: the value check is skipped there, not an error.
    import jax

    cam = jax.jit(lambda K: stage.Camera(K=K, R=good.R, t=good.t, width=8, height=6).K)(good.K)
    np.testing.assert_array_equal(np.asarray(cam), np.asarray(good.K))


_TRIANGLES = "vt 0 0\nvt 1 0\nvt 0 1\nvt 1 1\nf 1/1 2/2 3/3\nf 2/2 4/4 3/3\n"


def _obj(tmp_path, verts, tail=_TRIANGLES):
    path = tmp_path / "m.obj"
    path.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in verts) + tail)
    return path


def test_meshes_with_unusable_coordinates_are_refused_at_load(tmp_path):
    square = [(0, 0, 0), (10, 0, 0), (0, 10, 0), (10, 10, 0)]
    assert len(stage.load_mesh(_obj(tmp_path, square)).faces) == 2
    # Coordinates whose squares overflow float32 (the 1e35), or just past the stated limit.
    with pytest.raises(ValueError, match=r"m\.obj: a vertex coordinate is 1e\+35 mm .*MAX_COORDINATE_MM"):
        stage.load_mesh(_obj(tmp_path, [(0, 0, 0), (1e35, 0, 0), (0, 1e35, 0), (1e35, 1e35, 0)]))
    with pytest.raises(ValueError, match=r"after scale 20"):
        stage.load_mesh(_obj(tmp_path, [(x * MAX_COORDINATE_MM / 10, y, z) for x, y, z in square]), scale=20.0)
    for bad in ("nan", "inf"):
        with pytest.raises(ValueError, match=r"m\.obj: 1 vertex position\(s\) are NaN or Inf \(first: vertex 3\)"):
            stage.load_mesh(_obj(tmp_path, square[:3] + [(bad, 0, 0)]))
    nan_uv = "vt nan 0\nvt 1 0\nvt 0 1\nvt 1 1\nf 1/1 2/2 3/3\nf 2/2 4/4 3/3\n"
    with pytest.raises(ValueError, match=r"m\.obj: 1 UV coordinate\(s\) are NaN or Inf"):
        stage.load_mesh(_obj(tmp_path, square, nan_uv))
    with pytest.raises(ValueError, match=r"argument 'scale' must be positive and finite"):
        stage.load_mesh(_obj(tmp_path, square), scale=float("nan"))


def test_a_file_normal_that_is_not_finite_is_recomputed(tmp_path):
    square = [(0, 0, 0), (10, 0, 0), (0, 10, 0), (10, 10, 0)]
    faces = "f 1/1/1 2/2/1 3/3/1\nf 2/2/1 4/4/1 3/3/1"
    tail = "vn inf 0 1\n" + _TRIANGLES.replace("f 1/1 2/2 3/3\nf 2/2 4/4 3/3", faces)
    mesh = stage.load_mesh(_obj(tmp_path, square, tail))
    np.testing.assert_allclose(mesh.normals, np.tile([0.0, 0.0, 1.0], (4, 1)), atol=1e-12)


def _dome():
    return np.asarray(stage.geodesic_dome(0).position, np.float64)


@pytest.mark.parametrize("intensity, pattern", [
    (0.0, r"every light has intensity 0 \(make_rig's argument 'intensity'\)"),
    (np.zeros((12, 3)), r"every light has intensity 0"),
    (-1.0, r"finite \(in float32\) and non-negative \(make_rig's argument 'intensity'\)"),
    (float("nan"), r"finite \(in float32\) and non-negative"),
    (1e39, r"finite \(in float32\)"),  # finite in float64, Inf once stored as the rig's float32
])
def test_make_rig_refuses_dark_or_broken_intensities(intensity, pattern):
    with pytest.raises(ValueError, match=pattern):
        stage.make_rig(_dome(), intensity)


def test_one_dark_light_is_allowed_but_not_a_rig_calibrated_to_darkness():
    inten = np.ones((12, 3))
    inten[3] = 0.0  # a broken bulb: the rest still light the subject
    rig = stage.make_rig(_dome(), inten)
    assert float(rig.intensity[3].sum()) == 0.0 and float(rig.intensity.sum()) == 33.0
    with pytest.raises(ValueError, match=r"every light has intensity 0 \(make_rig's argument 'intensity' times "
                                         r"'calibration'\)"):
        stage.make_rig(_dome(), 1.0, calibration=0.0)
    with pytest.raises(ValueError, match=r"calibrate's argument 'gains'"):
        stage.calibrate(rig, [0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"argument 'position': a coordinate is 8\.51e\+37 mm"):
        stage.make_rig(_dome() * 1e35)


def test_rig_files_refuse_dark_rigs_and_malformed_fields(tmp_path):
    doc = stage.rig_to_dict(stage.geodesic_dome(0))
    path = tmp_path / "rig.json"
    cases = [({**doc, "intensities": 0.0}, r"rig\.json: field 'intensities': every light has intensity 0"),
             ({**doc, "intensities": [[0.0, 0.0, 0.0]] * 12}, r"field 'intensities': every light has intensity 0"),
             ({**doc, "solid_angles": ["abc"] * 12}, r"rig\.json: field 'solid_angles' must be \[L\] numbers"),
             ({**doc, "positions": [[1e300, 0, 0]] + doc["positions"][1:]},
              r"rig\.json: field 'positions' must be finite numbers within 1e\+09"),
             ({**doc, "positions": [["abc", 1, 2]] + doc["positions"][1:]},
              r"rig\.json: field 'positions' must be \[L, 3\] numbers \(could not convert string to float")]
    for bad, pattern in cases:
        path.write_text(json.dumps(bad))
        for read in (stage.load_rig, stage.load_rig_file):
            with pytest.raises(ValueError, match=pattern):
                read(path)
    for bad, pattern in [({**doc, "up": ["+y"]}, r"rig\.json: field 'up' must be one of"),
                         ({**doc, "units": {"positions": ["mm"]}, "near_field": "yes"},
                          r"rig\.json: field 'near_field' must be true or false")]:
        path.write_text(json.dumps(bad))
        with pytest.raises(ValueError, match=pattern):
            stage.load_rig_file(path)
    path.write_text(json.dumps({"intensities": [1.0]}))
    with pytest.raises(ValueError, match=r"rig\.json: rig needs field 'positions' or 'directions'"):
        stage.rig_file_subsets(path)


def test_rig_tables_refuse_huge_positions_and_declared_sizes(tmp_path):
    path = tmp_path / "lights.npy"
    np.save(path, _dome() * 1e300)
    with pytest.raises(ValueError, match=r"lights\.npy: light positions reach 8\.51e\+302"):
        stage.load_rig_file(path, units="mm", up="+y")
    np.save(path, _dome())
    path.write_bytes(path.read_bytes().replace(b"(12, 3)", b"(99999999999, 3)"))
    with pytest.raises(ValueError, match=r"lights\.npy: not a readable \.npy array"):
        stage.load_rig_file(path, units="mm", up="+y")


@pytest.mark.parametrize("text", ["1" * 5000, "[" * 100000])
def test_read_json_names_the_file_for_any_bad_document(tmp_path, text):
    path = tmp_path / "rig.json"
    path.write_text(text)
    with pytest.raises(ValueError, match=r"rig\.json: not valid JSON"):
        stage.load_rig(path)



def test_calibration_readers_name_what_is_not_a_regular_file(tmp_path):
    """stage.existing_path, the one check before a user's file is read: a FIFO (whose read would hang), a
    folder and a missing path are named, by every calibration reader, before any read."""
    import os

    fifo = tmp_path / "calib.yml"
    os.mkfifo(fifo)
    for read, what in ((stage.read_opencv_calibration, "OpenCV calibration file"),
                       (stage.read_metashape_xml, "Metashape camera file")):
        with pytest.raises(ValueError, match=rf"calib\.yml: is a FIFO \(named pipe\), not a regular file \({what}"):
            read(fifo, 1.0)
        with pytest.raises(ValueError, match=r"is a folder, not a regular file"):
            read(tmp_path, 1.0)
        with pytest.raises(FileNotFoundError, match=rf"nothing\.yml: no such {what}"):
            read(tmp_path / "nothing.yml", 1.0)
    with pytest.raises(ValueError, match="expected a COLMAP model folder, got a file"):
        stage.read_colmap(fifo, 1.0)

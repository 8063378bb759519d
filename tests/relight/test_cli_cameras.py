"""``relight cameras FORMAT PATH --units U --out cameras.json``: each format's calibration becomes a camera file
that stage.load_cameras reads back as the library's reader gave it (same projections), one printed line per
camera; bad units, a missing path, an unsupported model and a folder for --out exit 1 with one line naming the
problem; an unknown format is misuse (exit 2)."""

import json

import numpy as np
import pytest

import stage
from relight.cli import main
from tests.stage.test_calib_metashape import truth_rig, write_every_format

PX_TOL = 1e-3  # the camera file holds the float32 cameras as float64: the round trip is exact to float32


@pytest.fixture(scope="module")
def formats(tmp_path_factory):
    return write_every_format(tmp_path_factory.mktemp("calib"), truth_rig())


@pytest.mark.parametrize("fmt, key, units", [
    ("colmap", "colmap text", "m"), ("colmap", "colmap binary", "1000"), ("opencv", "opencv json", "cm"),
    ("opencv", "opencv yaml", "10"), ("metashape", "metashape", "1e3"),
])
def test_each_format_becomes_a_camera_file(tmp_path, capsys, formats, fmt, key, units):
    path, _ = formats[key]
    out = tmp_path / "cameras.json"
    assert main(["cameras", fmt, str(path), "--units", units, "--out", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("cam000: 1280x960 px, focal 1400.00 x 1380.00 px, distorted")
    assert lines[2].endswith("no distortion") and lines[-1] == f"wrote 3 camera(s) to {out}"
    expected = {"colmap": stage.read_colmap, "opencv": stage.read_opencv_calibration,
                "metashape": stage.read_metashape_xml}[fmt](path, float(units) if units[0].isdigit() else units)
    written = stage.load_cameras(out)
    X = np.random.default_rng(0).uniform(-150.0, 150.0, size=(32, 3))
    for cam, ref in zip(written, expected.values(), strict=True):
        np.testing.assert_allclose(np.asarray(cam.project(X)[0]), np.asarray(ref.project(X)[0]), atol=PX_TOL, rtol=0)
        np.testing.assert_array_equal(np.asarray(cam.dist), np.asarray(ref.dist))
    assert [c["name"] for c in json.loads(out.read_text())["cameras"]] == list(expected)


def test_quiet_twice_prints_nothing(tmp_path, capsys, formats):
    out = tmp_path / "cameras.json"
    assert main(["cameras", "opencv", str(formats["opencv json"][0]), "--units", "cm", "--out", str(out), "-qq"]) == 0
    assert capsys.readouterr().out == "" and out.is_file()


@pytest.mark.parametrize("argv, match", [
    (["colmap", "{colmap text}", "--units", "0"], "mm_per_unit"),
    (["colmap", "{colmap text}", "--units", "furlong"], "unknown unit 'furlong'"),
    (["colmap", "{colmap text}", "--units", "nan"], "mm_per_unit"),
    (["opencv", "{tmp}/nothing.yml", "--units", "mm"], "nothing.yml: no such OpenCV calibration file"),
    (["metashape", "{opencv json}", "--units", "m"], "opencv.json: not valid XML"),
])
def test_bad_inputs_exit_1_with_one_line(tmp_path, capsys, formats, argv, match):
    argv = [a.format(tmp=tmp_path, **{k: str(v[0]) for k, v in formats.items()}) for a in argv]
    assert main(["cameras", *argv, "--out", str(tmp_path / "c.json")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("relight cameras: error: ") and match in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "c.json").exists()


def test_an_unsupported_colmap_model_names_the_camera(tmp_path, capsys, formats):
    folder = formats["colmap text"][0]
    bad = tmp_path / "model"
    bad.mkdir()
    (bad / "images.txt").write_text((folder / "images.txt").read_text())
    (bad / "cameras.txt").write_text((folder / "cameras.txt").read_text().replace("OPENCV", "OPENCV_FISHEYE", 1))
    assert main(["cameras", "colmap", str(bad), "--units", "m", "--out", str(tmp_path / "c.json")]) == 1
    assert "cameras.txt: camera 1: model OPENCV_FISHEYE is not supported" in capsys.readouterr().err


def test_a_camera_name_with_a_folder_is_said_when_written(tmp_path, capsys, formats):
    """COLMAP keeps an image's subfolder in its name; the camera file is written as the model says, with one
    warning per such name (a photo capture's reader refuses it as a view folder name: said here, not later)."""
    folder = formats["colmap text"][0]
    sub = tmp_path / "model"
    sub.mkdir()
    (sub / "cameras.txt").write_text((folder / "cameras.txt").read_text())
    text = (folder / "images.txt").read_text()
    assert text.count(" cam001\n") == 1
    (sub / "images.txt").write_text(text.replace(" cam001\n", " left/cam001\n"))
    out = tmp_path / "c.json"
    assert main(["cameras", "colmap", str(sub), "--units", "m", "--out", str(out)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "camera name: 'left/cam001' is not a plain file name" in err[0], err
    assert [c["name"] for c in json.loads(out.read_text())["cameras"]] == ["cam000", "left/cam001", "cam002"]


def test_a_folder_for_out_is_refused(tmp_path, capsys, formats):
    assert main(["cameras", "colmap", str(formats["colmap text"][0]), "--units", "m", "--out", str(tmp_path)]) == 1
    assert "--out names the camera file to write" in capsys.readouterr().err


def test_an_unknown_format_is_misuse(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["cameras", "bundler", str(tmp_path), "--units", "m", "--out", str(tmp_path / "c.json")])
    assert exc.value.code == 2
    assert "invalid choice: 'bundler'" in capsys.readouterr().err

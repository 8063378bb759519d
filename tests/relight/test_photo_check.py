"""A photo capture checked before any fitting (issue 28, item 3): ``relight.io.check_photo_capture`` and
``relight info PHOTOS_DIR`` summarise it and name the likely mistakes of a delivery; reading PNG values with no
stated exposure or gain warns that counts would be taken for radiance."""

import json

import numpy as np
import pytest

import stage
from relight.cli import main
from relight.io import check_photo_capture, read_photo_capture, write_photo_capture

L, H, W = 12, 12, 16


def _capture(tmp_path, name="p", images=None, fmt="exr", rig=None, cams=None, **kw):
    rig = stage.make_rig(stage.fibonacci_sphere(L).position * 1500.0 / 1000.0) if rig is None else rig
    cams = stage.camera_ring(2, 1000.0, width=W, height=H, fov_deg=20) if cams is None else cams
    if images is None:
        rng = np.random.default_rng(0)
        images = [rng.uniform(0.05, 0.6, (L, H, W, 3)).astype(np.float32) for _ in cams]
    return write_photo_capture(tmp_path / name, images, rig, cams, fmt=fmt, **kw)


def _edit(path, fn):
    doc = json.loads(path.read_text())
    fn(doc)
    path.write_text(json.dumps(doc))


def test_a_good_capture_has_no_warnings_and_its_numbers(tmp_path):
    """Values uniform in [0.05, 0.6] x exposure 2: nothing dark or saturated, every light lit, radiance range
    within [0.025, 0.3]."""
    folder = _capture(tmp_path, exposure=[2.0, 2.0])
    check = check_photo_capture(read_photo_capture(folder), stride=1)
    assert check.warnings == []
    v = check.views[0]
    assert v["lights_lit"] == L and v["saturated_fraction"]["max"] == 0 and v["dark_fraction"]["median"] == 0
    assert 0.025 <= v["radiance_range"][0] < v["radiance_range"][1] <= 0.3
    assert v["subject_pixels_sampled"] == H * W and check.rig["near_field"]


def test_png_counts_with_no_gain_are_said(tmp_path):
    """A 16-bit PNG delivery stored at 40000 counts per unit radiance, capture.json without 'gain': the check
    and the reader both say that counts are read as fractions of full scale (0.61 x the radiance)."""
    folder = _capture(tmp_path, fmt="png")
    assert json.loads((folder / "capture.json").read_text())["views"][0]["gain"] == 1.0  # the writer says it
    _edit(folder / "capture.json", lambda d: [v.pop("gain") for v in d["views"]])
    cap = read_photo_capture(folder)
    assert cap.unscaled_png(0) and cap.unscaled_png(1)
    check = check_photo_capture(cap)
    assert sum("PNG values with no 'exposure' or 'gain'" in w for w in check.warnings) == 2
    with pytest.warns(UserWarning, match=r"capture\.json: view 'cam000' reads PNGs .* state 'gain'"):
        cap.read_view(0)
    # Stated, the same values read silently, scaled: gain 40000 / 65535 divides them by 0.61.
    _edit(folder / "capture.json", lambda d: d.update(gain=40000 / 65535))
    stated = read_photo_capture(folder)
    assert not stated.unscaled_png(0) and check_photo_capture(stated).warnings == []
    np.testing.assert_allclose(stated.read_view(0).radiance * (40000 / 65535),
                               read_photo_capture(_capture(tmp_path, "q", fmt="png")).read_view(0).radiance,
                               rtol=1e-6)


def test_saturated_and_black_images_are_said(tmp_path):
    ones = [np.ones((L, H, W, 3), np.float32)] * 2
    check = check_photo_capture(read_photo_capture(_capture(tmp_path, "s", ones, fmt="png")))
    assert any("most of the subject is saturated" in w for w in check.warnings)
    black = [np.full((L, H, W, 3), 1e-4, np.float32)] * 2
    check = check_photo_capture(read_photo_capture(_capture(tmp_path, "b", black, fmt="png")))
    assert sum("every image is dark on the subject" in w for w in check.warnings) == 2


def test_a_rig_in_metres_read_as_mm_and_a_flipped_rig_are_said(tmp_path):
    pos = np.asarray(stage.fibonacci_sphere(L).position, np.float64)
    pos = 1500.0 * pos / np.linalg.norm(pos, axis=1, keepdims=True)
    metres = stage.make_rig(pos / 1000.0)  # 1.5 "mm" from the centre
    check = check_photo_capture(read_photo_capture(_capture(tmp_path, "m", rig=metres)))
    assert any("lights lie within 100 mm of the rig centre" in w for w in check.warnings)
    # Every light behind the subject as the cameras see it (z < 0; the ring's first camera sits at +z).
    back = stage.make_rig(np.where(pos[:, 2:] > 0, pos * [1, 1, -1], pos))
    cams = stage.camera_ring(1, 1000.0, width=W, height=H, fov_deg=20)
    check = check_photo_capture(read_photo_capture(_capture(tmp_path, "f", rig=back, cams=cams,
                                                            images=[np.full((L, H, W, 3), 0.3, np.float32)])))
    assert any("no light is on its side of the subject" in w for w in check.warnings)


def test_a_camera_looking_away_is_said(tmp_path):
    away = stage.look_at((0.0, 0.0, 1000.0), (0.0, 0.0, 2000.0), width=W, height=H)
    cams = (stage.camera_ring(1, 1000.0, width=W, height=H)[0], away)
    check = check_photo_capture(read_photo_capture(_capture(tmp_path, "a", cams=cams)))
    assert [w for w in check.warnings if "rig centre is not in its image" in w] == [
        "camera 'cam001': the rig centre is not in its image (behind it or outside the frame): check R and t in "
        "cameras.json (world to camera, mm)"]


def test_relight_info_prints_the_summary_and_the_warnings(tmp_path, capsys):
    folder = _capture(tmp_path, fmt="png")
    _edit(folder / "capture.json", lambda d: [v.pop("gain") for v in d["views"]])
    assert main(["info", str(folder), "--stride", "2"]) == 0
    out = capsys.readouterr().out
    assert f"{folder}: 2 cameras, {L} lights (near field" in out
    assert "cam000: 16x12 png (no exposure/gain)" in out and "lights lit 12" in out
    assert out.count("warning: camera") == 2
    assert main(["info", str(folder), "--stride", "0"]) == 1
    assert "--stride 0: must be at least 1" in capsys.readouterr().err

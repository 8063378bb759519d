"""A Mitsuba-rendered photo capture read through four camera files (scripts/eval_mitsuba_photos.py, small).

Mitsuba 3 renders the head from two cameras with an off-centre principal point under 12 Light Stage X lights;
the capture is written as a stage delivers it (16-bit PNG counts + gain, cameras.json in OpenCV's pixel
convention, masks) and fitted with (a) its cameras.json, (b) the file hand-converted to "colmap" (cx, cy + 0.5),
(c) a COLMAP text model of the cameras through ``relight cameras colmap``, (d) the old misreading (the OpenCV
K taken as the Camera's). Issue 28's first done-when: (a), (b), (c) project alike to 1e-3 px and fit alike.
"""

import numpy as np
import pytest

from ..helpers import load_script

# 64 px images, 16 lights, 2 cameras, 4 spp, 24 x 24 texels: ~20 s on 2 cores, most of it the fit's compilation.
SMALL = dict(size=64, lights=16, cameras=2, spp=4, resolution=24)
# (a), (b), (c) hold the same cameras up to float32 rounding of K and the quaternion round trip of R: their
# projections agree far inside 1e-3 px (the bar), so their bilinear taps and fits agree to ~1e-5.
PROJECTION_TOL_PX = 1e-3
ALBEDO_SAME_TOL = 1e-4
# Measured median albedo relative error of reading (a) at SMALL: 0.034 over 142 fitted texels (64 px images: a
# pixel spans ~3 mm of the head, and each texel blends four of them over the texture's contrast); the bar leaves
# ~1.8x margin for spp noise and platform differences.
ALBEDO_BAR = 0.06
# The half-pixel misreading is at least this many times worse at the median (measured: 0.129, 3.8x).
MISREAD_FACTOR = 2.0


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    pytest.importorskip("mitsuba", reason="Mitsuba 3 renders the capture (a test extra: pip install -e '.[test]')")
    script = load_script("eval_mitsuba_photos")
    return script, script.run(**SMALL, work=tmp_path_factory.mktemp("mitsuba_photos"), progress=None, ladder=False)


def test_mitsuba_renders_where_the_cameras_say(result):
    script, r = result
    for cam in r["render"]["cameras"]:
        assert cam["sensor_agreement_px"] <= script.SENSOR_TOL_PX, cam
        assert cam["mask_pixels"] > 600, cam  # the head fills a quarter of each 64 x 64 image (measured ~950)
    assert r["render"]["clipped_fraction"] < 1e-3
    assert 0.05 < r["render"]["peak_radiance"] < 1.0 / script.GAIN


def test_the_three_correct_readings_project_alike_and_the_misreading_by_half_a_pixel(result):
    _, r = result
    p = r["projection_max_px"]
    for k in ("opencv", "hand_converted", "colmap", "read_colmap", "file_level_only_load_cameras"):
        assert p[k] <= PROJECTION_TOL_PX, (k, p[k])
    assert p["misread"] == pytest.approx(0.5, abs=PROJECTION_TOL_PX)


def test_read_photo_capture_honours_a_file_level_convention(result):
    """A file that says "colmap" only at its top applies it to every camera (stage.cameras_from_doc)."""
    _, r = result
    assert r["projection_max_px"]["file_level_only_read_photo_capture"] <= PROJECTION_TOL_PX


def test_the_three_correct_readings_fit_the_same_maps(result):
    _, r = result
    fits = r["fits"]
    ref = fits["opencv"]
    for k in ("hand_converted", "colmap"):
        np.testing.assert_array_equal(fits[k]["ok"], ref["ok"])
        ok = ref["ok"]
        np.testing.assert_allclose(fits[k]["rho_d"][ok], ref["rho_d"][ok], rtol=0, atol=ALBEDO_SAME_TOL)


def test_the_albedo_error_is_small_and_the_misreading_worse(result):
    _, r = result
    rows = {row["reading"]: row for row in r["rows"]}
    assert rows["opencv"]["fitted"] > 100  # measured 142 of 214 seen
    assert rows["opencv"]["albedo_rel"] < ALBEDO_BAR, rows["opencv"]
    assert rows["misread"]["albedo_rel"] > MISREAD_FACTOR * rows["opencv"]["albedo_rel"], rows
    common = {k: row["common"]["albedo_rel"] for k, row in rows.items()}
    assert common["misread"] > MISREAD_FACTOR * common["opencv"], common

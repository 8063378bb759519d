"""``relight render``'s outputs (issue 18): one exposure rule metered on the
subject, ``--background black|env|alpha`` with the coverage as relit.exr's A
and the settings in its header, a map set without a rig refused, ``--image-size``
scaling a camera file's cameras, every camera of a camera file rendered, and a
warning for subject pixels on texels no capture camera saw.

One tiny capture (the head at 16 x 16 texels under a 42-light dome, one 32 x 32
camera) and its simulated truth map set serve every test."""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import stage
from relight.cli import main
from relight.image import SUBJECT_KEY, luminance, subject_exposure, texture_view
from relight.io import exr_header, load_texel_maps, read_exr, read_png, write_exr, write_maps

from ._cli_runs import HEAD16_SIMULATE, head16

RES = 16
SIZE = 32
assert HEAD16_SIMULATE[1:7] == ["--rig", "dome:42", "--resolution", str(RES), "--image-size", str(SIZE)]


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """(folder for this module's outputs, the run's shared capture (tests/relight/_cli_runs.py), white.exr)."""
    root = tmp_path_factory.mktemp("render_outputs")
    cap, _ = head16(tmp_path_factory)
    white = root / "white.exr"
    write_exr(white, np.ones((16, 32, 3), np.float32))
    return root, cap, white


def _settings(out):
    return json.loads((out / "settings.json").read_text())["resolved"]


def _exposure(out) -> float:
    return _settings(out)["preview_exposure_stops"]


# ---------------------------------------------------------------- 1. the exposure rule


def test_subject_exposure_meters_the_subject_only():
    """The median subject luminance goes to SUBJECT_KEY; background pixels (coverage 0), however bright, and
    a partly covered edge pixel (unpremultiplied) do not move it."""
    rgb = np.zeros((8, 8, 3))
    cov = np.zeros((8, 8))
    rgb[2:6, 2:6] = [0.2, 0.1, 0.05]  # subject, fully covered
    cov[2:6, 2:6] = 1.0
    rgb[1, 2:6] = 0.5 * np.array([0.2, 0.1, 0.05])  # an edge row half covered: premultiplied, same colour
    cov[1, 2:6] = 0.5
    lum = 0.2126 * 0.2 + 0.7152 * 0.1 + 0.0722 * 0.05
    want = math.log2(SUBJECT_KEY / lum)
    assert abs(subject_exposure(rgb, cov) - want) < 1e-12
    bright = rgb.copy()
    bright[cov == 0] = 1000.0  # a blinding sky behind the subject
    assert abs(subject_exposure(bright, cov) - want) < 1e-12
    # Without a coverage the positive pixels are the subject (texel-space previews).
    assert abs(subject_exposure(rgb[2:6, 2:6]) - want) < 1e-12
    assert np.allclose(luminance(np.eye(3)), [0.2126, 0.7152, 0.0722])
    assert subject_exposure(np.zeros((4, 4, 3)), np.ones((4, 4))) == 0.0  # nothing to meter
    with pytest.raises(ValueError, match="percentile"):
        subject_exposure(rgb, cov, percentile=101)
    with pytest.raises(ValueError, match="coverage"):
        subject_exposure(rgb, np.ones((3, 3)))


def test_image_and_model_based_previews_of_the_same_radiance_share_an_exposure(setup):
    """The capture relit image-based and its truth maps rendered model-based (through the capture's rig and
    camera) under a constant environment see the same radiance; with the environment behind the subject
    (which the model-based frame used to be metered on, 2 stops off) they get one exposure within 0.05
    stops."""
    root, cap, white = setup
    a, b = root / "white_cap", root / "white_truth"
    assert main(["render", str(cap), "--envmap", str(white), "--background", "env", "--out", str(a),
                 "--quiet"]) == 0
    assert main(["render", str(cap / "truth"), "--envmap", str(white), "--background", "env", "--rig",
                 str(cap / "rig.json"), "--camera", str(cap / "cameras.json"), "--out", str(b), "--quiet"]) == 0
    assert abs(_exposure(a) - _exposure(b)) < 0.05, (_exposure(a), _exposure(b))
    # The rule is what settings.json says: the subject's median luminance (A >= 0.5) at SUBJECT_KEY.
    img = read_exr(b / "relit.exr")
    want = subject_exposure(img[..., :3] - (1 - img[..., 3:]), img[..., 3])  # a white env behind adds 1 - A
    assert abs(_exposure(b) - want) < 1e-4


def test_a_bright_background_does_not_change_the_exposure(setup):
    """Under the sunset map, --background env composites the environment behind the subject (A = 0 pixels
    show it, bright) but the exposure is the black render's, to 1e-9 stops; env - black is the environment
    weighted by 1 - A, nothing on fully covered pixels."""
    root, cap, _ = setup
    black, env = root / "sun_black", root / "sun_env"
    assert main(["render", str(cap), "--background", "black", "--out", str(black), "--quiet"]) == 0
    assert main(["render", str(cap), "--background", "env", "--out", str(env), "--quiet"]) == 0
    assert abs(_exposure(black) - _exposure(env)) < 1e-9
    k, e = read_exr(black / "relit.exr"), read_exr(env / "relit.exr")
    np.testing.assert_array_equal(k[..., 3], e[..., 3])
    empty, full = k[..., 3] == 0, k[..., 3] == 1
    assert empty.sum() > 100 and full.sum() > 100
    assert np.all(k[empty][:, :3] == 0)
    sky = luminance(e[empty][:, :3])
    assert np.median(sky) > 2 * np.median(luminance(k[full][:, :3])), "the test needs a background brighter " \
                                                                        "than the subject"
    np.testing.assert_allclose(e[full][:, :3], k[full][:, :3], atol=1e-6)
    assert np.all(e[..., :3] >= k[..., :3] - 1e-6)


# ---------------------------------------------------------------- 2. backgrounds, alpha, header


def test_alpha_is_the_coverage_and_the_header_records_the_settings(setup):
    """relit.exr's A is the fraction of each pixel the mesh covers (checked against relight.image.texture_view
    of a texture of ones, the renderers' 2 x 2 sub-pixel rays); --background alpha writes the same EXR as
    black and an RGBA PNG whose alpha is A; the header holds the env map, rotation, camera and method."""
    root, cap, _ = setup
    out_a, out_k = root / "alpha", root / "alpha_black"
    argv = ["render", str(cap), "--rotate", "30", "--out"]
    assert main([*argv, str(out_a), "--background", "alpha", "--quiet"]) == 0
    assert main([*argv, str(out_k), "--quiet"]) == 0
    img = read_exr(out_a / "relit.exr")
    np.testing.assert_array_equal(img, read_exr(out_k / "relit.exr"))
    mesh = load_texel_maps(cap / "truth").mesh
    camera = stage.load_cameras(cap / "cameras.json")[0]
    ones = texture_view(mesh, camera, {"one": np.ones((4, 4, 1), np.float32)})["one"][..., 0]
    np.testing.assert_allclose(img[..., 3], ones, atol=1e-6)
    assert 0 < img[..., 3].mean() < 1 and np.any((img[..., 3] > 0) & (img[..., 3] < 1))
    png = read_png(out_a / "relit.png")
    assert png.shape == (SIZE, SIZE, 4)
    assert np.abs(png[..., 3].astype(float) / 255 - img[..., 3]).max() <= 0.5 / 255 + 1e-6
    assert read_png(out_k / "relit.png").shape == (SIZE, SIZE, 3)
    head = exr_header(out_a / "relit.exr")
    settings = _settings(out_a)
    assert head["relight:envmap"] == settings["envmap"] and head["relight:envmap"].endswith(".hdr")
    assert head["relight:rotation_deg"] == 30.0
    assert head["relight:camera"] == stage.camera_to_dict(camera)
    assert head["relight:method"] == settings["method"] and head["relight:background"] == "alpha"
    assert abs(head["relight:preview_exposure_stops"] - settings["preview_exposure_stops"]) < 1e-6


# ---------------------------------------------------------------- 3. rigs, image size, cameras, unseen texels


def test_a_map_set_without_a_rig_is_refused_or_takes_its_captures(setup, capsys):
    """The truth map set records no rig: --method rig refuses (naming --rig) rather than rendering under the
    Light Stage X; a set that records the capture it came from takes that capture's rig.json."""
    root, cap, white = setup
    out = root / "no_rig"
    assert main(["render", str(cap / "truth"), "--out", str(out), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "no rig.json" in err and "--rig" in err
    assert not out.exists()
    textures, maps, surface, _, _, _ = load_texel_maps(cap / "truth")
    linked = root / "linked"
    rel = os.path.relpath(cap, linked)  # a relative path, resolved against the set's own folder
    write_maps(linked, maps, surface, surface_info=textures.surface_info, metadata={"capture": rel})
    out = root / "linked_render"
    assert main(["render", str(linked), "--envmap", str(white), "--camera", str(cap / "cameras.json"),
                 "--out", str(out), "--quiet"]) == 0
    assert f"{linked / rel / 'rig.json'}" in _settings(out)["method"]


def test_image_size_scales_a_camera_files_cameras(setup):
    """--image-size 16 with a 32 x 32 camera file: a 16 x 16 image whose intrinsics are halved, so the subject
    sits where it did: the coverage is the 2 x 2 mean of the full-size one within 0.05 (mean abs)."""
    root, cap, _ = setup
    full, half = root / "size_full", root / "size_half"
    cams = str(cap / "cameras.json")
    assert main(["render", str(cap), "--camera", cams, "--out", str(full), "--quiet"]) == 0
    assert main(["render", str(cap), "--camera", cams, "--image-size", "16", "--out", str(half), "--quiet"]) == 0
    a, b = read_exr(full / "relit.exr")[..., 3], read_exr(half / "relit.exr")[..., 3]
    assert b.shape == (16, 16)
    # Halved in continuous coordinates: the files' K is OpenCV's (pixel centres at integers), + 0.5 on cx, cy.
    shift = np.array([[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]])
    K_half, K_full = (np.array(_settings(f)["camera"]["K"]) + shift for f in (half, full))
    np.testing.assert_allclose(K_half, np.diag([0.5, 0.5, 1.0]) @ K_full, rtol=1e-6)
    assert np.abs(a.reshape(16, 2, 16, 2).mean(axis=(1, 3)) - b).mean() < 0.05


def test_every_camera_is_rendered_and_unseen_texels_are_reported(setup, capsys):
    """A camera file of two cameras (the capture's, and one orbited 100 degrees) gives cam000/ and cam001/;
    cam000's frame is the single-camera render's, and the side view, which sees texels the capture's one
    camera never saw (no radiance: black, or dimmed where the lookup blends them in), is warned about with
    the fraction of its subject pixels mostly on them. Under a constant environment the relit radiance is
    ~albedo x occlusion, so that fraction lies between the share of subject pixels that came out black (all
    on such texels) and the share dimmer than half the median (at most half on data; 0.02 for the one or two
    pixels that occlusion dims instead)."""
    root, cap, white = setup
    front = stage.load_cameras(cap / "cameras.json")[0]
    from relight.render import orbit_camera

    two = root / "two.json"
    stage.save_cameras(two, [front, orbit_camera(front, math.radians(100.0))])
    single, out = root / "cam_single", root / "cam_two"
    argv = ["render", str(cap), "--envmap", str(white), "--quiet", "--camera"]
    assert main([*argv, str(cap / "cameras.json"), "--out", str(single)]) == 0
    capsys.readouterr()
    assert main([*argv, str(two), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert not (out / "relit.exr").exists()
    a, b = read_exr(out / "cam000" / "relit.exr"), read_exr(out / "cam001" / "relit.exr")
    np.testing.assert_array_equal(a, read_exr(single / "relit.exr"))
    assert (out / "cam001" / "relit.png").is_file()
    assert not np.array_equal(a[..., 3], b[..., 3])
    settings = _settings(out)
    assert settings["outputs"] == ["cam000/relit.exr", "cam001/relit.exr"] and len(settings["cameras"]) == 2
    unseen = settings["unseen_pixel_fraction"]
    assert unseen[0] < 1e-3 < 0.05 < unseen[1], unseen
    lum = luminance(b[..., :3])[b[..., 3] >= 0.5]
    black, dim = np.mean(lum <= 0), np.mean(lum < 0.5 * np.median(lum[lum > 0]))
    assert black <= unseen[1] <= dim + 0.02, (black, unseen[1], dim)
    assert "warning (camera 1)" in err and f"{100 * unseen[1]:.1f}%" in err and "camera 0" not in err


def test_environment_behind_is_the_renderers_own_background(setup):
    """relight.render.environment_behind (what --background env adds) is exactly what render_view's own
    background adds: render_view(background=True) - render_view(background=False), rotated or not (1e-5:
    float32 radiance of order 1)."""
    from relight.envmap import bundled_envmap_path, load_envmap, rotation_matrix
    from relight.render import environment_behind, render_view

    _, cap, _ = setup
    t = load_texel_maps(cap / "truth")
    camera = stage.load_cameras(cap / "cameras.json")[0]
    env = load_envmap(bundled_envmap_path())
    rig = stage.load_rig(cap / "rig.json")
    rot = np.asarray(rotation_matrix(np.array([0.0, 1.0, 0.0]), np.deg2rad(70.0)), np.float64)
    for r in (None, rot):
        on = render_view(t.maps, t.surface, t.mesh, camera, env, rig=rig, rotation=r, background=True)
        off = render_view(t.maps, t.surface, t.mesh, camera, env, rig=rig, rotation=r, background=False)
        behind = environment_behind(env, t.mesh, camera, rotation=r)
        assert behind.max() > 0.1
        np.testing.assert_allclose(on - off, behind, atol=1e-5)


def test_a_fixed_exposure_is_used_as_given(setup):
    """--exposure EV: settings.json and the header record EV, and relit.png is relit.exr's RGB tone-mapped
    at EV (relight.image.tonemap, filmic), to one 8-bit level."""
    from relight.image import to_uint8, tonemap

    root, cap, _ = setup
    out = root / "fixed"
    assert main(["render", str(cap), "--exposure", "-1.5", "--out", str(out), "--quiet"]) == 0
    s = _settings(out)
    assert s["preview_exposure_stops"] == -1.5 and s["exposure_from"] == "--exposure"
    assert exr_header(out / "relit.exr")["relight:preview_exposure_stops"] == -1.5
    img = read_exr(out / "relit.exr")[..., :3]
    want = to_uint8(tonemap(img, exposure=-1.5, curve="filmic")).astype(int)
    assert np.abs(read_png(out / "relit.png").astype(int) - want).max() <= 1


# relight.cli loaded under an empty ``relight`` package (as tests/relight/test_cli_ux.py does for the other
# commands), so the check sees the CLI's own imports, not relight/__init__'s.
_HELP = """
import sys, types
pkg = types.ModuleType("relight"); pkg.__path__ = [{root!r} + "/relight"]; sys.modules["relight"] = pkg
from relight.cli import main
try:
    main(["render", "--help"])
except SystemExit as exc:
    assert exc.code == 0, exc.code
print("HEAVY", sorted(m for m in sys.modules if m.split(".")[0] in ("jax", "jaxlib", "stage", "brdf")
                      or (m.startswith("relight.") and m.split(".")[1] != "cli")))
"""


def test_render_help_imports_no_jax_and_spells_the_librarys_methods():
    import relight.render
    from relight.cli import render

    root = Path(__file__).resolve().parents[2]
    out = subprocess.run([sys.executable, "-c", _HELP.format(root=str(root))], capture_output=True, text=True,
                         timeout=60, cwd=root)
    assert out.returncode == 0, out.stderr
    assert "HEAVY []" in out.stdout and "--background" in out.stdout, out.stdout[-600:]
    assert render.METHODS == tuple(relight.render.METHODS)

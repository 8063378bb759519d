"""``relight simulate -> fit -> render`` end to end on a tiny problem (the head
at 16x16 texels under a 42-light geodesic dome), and the failure paths:
missing or corrupt inputs, a folder that is neither a capture nor a map set,
an unknown method, missing arguments."""

import json
import shutil

import numpy as np
import pytest

from relight.cli import main
from relight.io import read_capture, read_exr, read_maps, write_exr

from ._cli_runs import HEAD16_SIMULATE, head16

RES = 16
LIGHTS = 42
assert HEAD16_SIMULATE[1:7] == ["--rig", f"dome:{LIGHTS}", "--resolution", str(RES), "--image-size", "32"]


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory):
    """(folder for this module's outputs, capture, map set, white.exr): the run's shared `relight simulate --rig
    dome:42 --resolution 16 --image-size 32` and its default `relight fit` (tests/relight/_cli_runs.py)."""
    root = tmp_path_factory.mktemp("pipeline")
    cap, maps = head16(tmp_path_factory)
    white = root / "white.exr"
    write_exr(white, np.ones((16, 32, 3), np.float32))
    return root, cap, maps, white


def test_simulate_writes_a_capture_folder(pipeline):
    _, cap, _, _ = pipeline
    data = read_capture(cap)
    assert data.radiance.shape == (1, LIGHTS, RES * RES, 3)
    assert data.sample_shape == (RES, RES)
    assert data.valid is not None and data.valid.any()
    assert np.all(data.radiance[~np.broadcast_to(data.valid, data.radiance.shape[:3])] == 0)
    meta = data.metadata
    assert meta["space"] == "texel" and meta["surface"]["resolution"] == [RES, RES]
    assert meta["surface"]["bundled"] == "head"
    settings = json.loads((cap / "settings.json").read_text())
    assert settings["command"] == "relight simulate"
    assert settings["flags"]["rig"] == f"dome:{LIGHTS}" and settings["resolved"]["lights"] == LIGHTS
    assert (cap / "preview_all_lights.png").is_file() and (cap / "preview_all_lights.exr").is_file()
    truth, _ = read_maps(cap / "truth")
    assert truth.resolution == (RES, RES)


def test_fit_recovers_the_simulated_truth(pipeline):
    _, _, maps, _ = pipeline
    report = json.loads((maps / "report.json").read_text())
    truth = report["against_truth"]
    # Issue 2's bar on noise-free data: albedo within 2%, roughness within 10% (medians).
    assert truth["errors"]["diffuse_albedo_rel"]["unflagged"]["median"] < 0.02
    assert truth["errors"]["roughness_rel"]["unflagged"]["median"] < 0.10
    assert not any("_rel_error_" in k for k in truth)  # the flat copies are gone
    assert report["failed_fraction"] < 0.1
    # Noise-free: no albedo is loose enough to be called ambiguous (1-sigma above 10%).
    assert report["ambiguous_fraction"] < 0.02
    tex, info = read_maps(maps)
    assert tex.resolution == (RES, RES) and info["bundled"] == "head"
    assert tex.coverage.sum() == report["samples"]
    for name in ("scene.xml", "mesh.obj", "settings.json", "report.md", "albedo.png", "albedo_view.png",
                 "albedo_view.exr", "mitsuba/diffuse_x2.exr"):
        assert (maps / name).is_file(), name
    settings = json.loads((maps / "settings.json").read_text())
    assert settings["flags"]["solver"] == "lm" and "method" not in settings["flags"]
    assert not list(maps.glob(".*tmp*"))


def test_render_capture_under_a_white_environment(pipeline):
    """Image-based relighting under a constant environment of radiance 1: each
    texel shows its directional albedo times its unoccluded fraction, i.e. the
    diffuse albedo (less occlusion, plus a few % of specular). The median ratio to
    the albedo seen through the same camera is therefore near 1; 0.7..1.15
    allows for the ear/nose occlusion and the dome's 42-light discretisation."""
    root, cap, maps, white = pipeline
    out = root / "render_capture"
    assert main(["render", str(cap), "--envmap", str(white), "--out", str(out), "--quiet"]) == 0
    img = read_exr(out / "relit.exr")[..., :3]  # RGB; A is the coverage
    albedo = read_exr(maps / "albedo_view.exr")
    assert img.shape == albedo.shape == (32, 32, 3)
    seen = albedo.min(-1) > 0.05
    assert seen.sum() > 50
    ratio = np.median(img[seen] / albedo[seen], axis=0)
    assert np.all(ratio > 0.7) and np.all(ratio < 1.15), ratio
    settings = json.loads((out / "settings.json").read_text())
    assert settings["resolved"]["input_kind"] == "capture" and settings["resolved"]["method"].startswith("rig")
    assert (out / "relit.png").is_file()


def test_render_turntable(pipeline):
    root, cap, _, _ = pipeline
    out = root / "turntable"
    assert main(["render", str(cap), "--out", str(out), "--frames", "3", "--rotate", "30", "--quiet"]) == 0
    frames = [read_exr(out / f"relit_{k:03d}.exr") for k in range(3)]
    settings = json.loads((out / "settings.json").read_text())
    assert settings["resolved"]["rotations_deg"] == [30.0, 150.0, 270.0]
    for f in frames:
        assert np.all(np.isfinite(f)) and f.min() >= 0 and f.max() > 0
    # The sunset map is far from uniform: turning it changes the picture.
    assert np.abs(frames[0] - frames[1]).mean() > 0.05 * frames[0].mean()


def _render_view():
    try:
        from relight.render import render_view
    except ImportError:
        pytest.skip("relight.render.render_view is not available in this build (model-based rendering)")
    return render_view


def test_render_maps_model_based_agrees_with_image_based(pipeline):
    """The fitted maps rendered model-based (method rig, with the capture's rig,
    which the map set keeps) and the capture relit image-based under the same
    constant environment see the same material through the same lights: the
    median pixel ratio is 1 within 3% (fit residual, and the texel-vs-pixel
    resampling of the two paths)."""
    _render_view()
    root, cap, maps, white = pipeline
    out_m, out_c = root / "render_maps", root / "render_capture_2"
    assert main(["render", str(maps), "--envmap", str(white), "--out", str(out_m), "--frames", "2", "--quiet"]) == 0
    assert main(["render", str(cap), "--envmap", str(white), "--out", str(out_c), "--quiet"]) == 0
    a, b = read_exr(out_m / "relit_000.exr")[..., :3], read_exr(out_c / "relit.exr")[..., :3]
    # A constant environment looks the same turned by 180 degrees: the second
    # turntable frame equals the first up to the rig weights' pixelisation of
    # the Voronoi cell boundaries (~1%).
    a2 = read_exr(out_m / "relit_001.exr")[..., :3]
    assert np.median(np.abs(a2 - a)) <= 0.02 * np.median(a[a > 0])
    assert a.shape == b.shape
    both = (a.min(-1) > 0.02) & (b.min(-1) > 0.02)
    assert both.sum() > 50
    np.testing.assert_allclose(np.median(a[both] / b[both], axis=0), 1.0, atol=0.03)
    settings = json.loads((out_m / "settings.json").read_text())
    assert settings["resolved"]["input_kind"] == "maps" and "capture's rig" in settings["resolved"]["method"]


# ---------------------------------------------------------------- failures


def test_fit_missing_capture_names_the_folder(tmp_path, capsys):
    assert main(["fit", str(tmp_path / "nowhere"), "--model", "ggx", "--out", str(tmp_path / "o"), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "nowhere" in err and "Traceback" not in err


def test_fit_corrupt_light_image_names_the_file(pipeline, tmp_path, capsys):
    _, cap, _, _ = pipeline
    broken = tmp_path / "cap"
    shutil.copytree(cap, broken)
    victim = broken / "views" / "v000" / "l007.exr"
    data = victim.read_bytes()
    victim.write_bytes(data[: len(data) // 3])
    assert main(["fit", str(broken), "--model", "ggx", "--out", str(tmp_path / "o"), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "l007.exr" in err and err.startswith("relight fit: error:")


def test_fit_method_is_a_usage_error(pipeline, tmp_path, capsys):
    """``fit --method`` (the solver's old name) is gone: argparse refuses it (``--solver`` is the flag)."""
    _, cap, _, _ = pipeline
    with pytest.raises(SystemExit) as exc:
        main(["fit", str(cap), "--model", "ggx", "--out", str(tmp_path / "o"), "--method", "simplex"])
    assert exc.value.code == 2
    assert "unrecognized arguments: --method simplex" in capsys.readouterr().err


def test_render_map_set_missing_albedo(pipeline, tmp_path, capsys):
    _, _, maps, _ = pipeline
    broken = tmp_path / "maps"
    shutil.copytree(maps, broken)
    (broken / "albedo.exr").unlink()
    _render_view()
    assert main(["render", str(broken), "--out", str(tmp_path / "o"), "--quiet"]) == 1
    assert "albedo.exr" in capsys.readouterr().err


def test_render_map_set_mismatched_resolution(pipeline, tmp_path, capsys):
    _, _, maps, _ = pipeline
    broken = tmp_path / "maps"
    shutil.copytree(maps, broken)
    write_exr(broken / "roughness.exr", np.ones((RES * 2, RES * 2, 3), np.float32),
              channels=["alpha_x", "alpha_y", "Y"])
    _render_view()
    assert main(["render", str(broken), "--out", str(tmp_path / "o"), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "roughness.exr" in err and "32x32" in err


def test_render_neither_capture_nor_maps(tmp_path, capsys):
    (tmp_path / "junk").mkdir()
    assert main(["render", str(tmp_path / "junk"), "--out", str(tmp_path / "o"), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "junk" in err and "neither a capture folder" in err


def test_render_wrong_method_for_the_input(pipeline, tmp_path, capsys):
    _, cap, maps, _ = pipeline
    assert main(["render", str(cap), "--out", str(tmp_path / "o"), "--method", "dense", "--quiet"]) == 1
    assert "--method dense" in capsys.readouterr().err
    assert main(["render", str(cap), "--out", str(tmp_path / "o"), "--rig", "dome:12", "--quiet"]) == 1
    assert "--rig dome:12" in capsys.readouterr().err
    assert main(["render", str(maps), "--out", str(tmp_path / "o"), "--method", "fast", "--rig", "lsx",
                 "--quiet"]) == 1
    assert "--rig lsx" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["render", str(cap), "--out", str(tmp_path / "o"), "--method", "magic"])
    assert exc.value.code == 2


def test_render_corrupt_envmap_names_the_file(pipeline, tmp_path, capsys):
    _, cap, _, _ = pipeline
    bad = tmp_path / "bad.hdr"
    bad.write_bytes(b"#?RADIANCE\nnot really\n")
    assert main(["render", str(cap), "--envmap", str(bad), "--out", str(tmp_path / "o"), "--quiet"]) == 1
    assert "bad.hdr" in capsys.readouterr().err


def test_simulate_bad_rig_and_noise(tmp_path, capsys):
    assert main(["simulate", "--rig", "dome:x", "--out", str(tmp_path / "o"), "--quiet"]) == 1
    assert "--rig dome:x" in capsys.readouterr().err
    assert main(["simulate", "--rig", str(tmp_path / "rig.json"), "--out", str(tmp_path / "o"), "--quiet"]) == 1
    assert "rig.json" in capsys.readouterr().err
    assert main(["simulate", "--noise", "loud", "--out", str(tmp_path / "o"), "--quiet"]) == 1
    assert "--noise loud" in capsys.readouterr().err
    assert main(["simulate", "--mesh", str(tmp_path / "none.obj"), "--out", str(tmp_path / "o"), "--quiet"]) == 1
    assert "none.obj" in capsys.readouterr().err


def test_simulate_refuses_to_replace_a_non_capture_folder(tmp_path, capsys):
    out = tmp_path / "precious"
    out.mkdir()
    (out / "thesis.tex").write_text("do not delete")
    assert main(["simulate", "--rig", "dome:12", "--resolution", "8", "--out", str(out), "--quiet"]) == 1
    assert "precious" in capsys.readouterr().err
    assert (out / "thesis.tex").read_text() == "do not delete"


@pytest.mark.parametrize("argv", [["fit"], ["render", "x"], ["simulate"]])
def test_missing_arguments_print_usage(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert f"usage: relight {argv[0]}" in capsys.readouterr().err


def test_info_lists_versions_and_data(capsys):
    assert main(["info"]) == 0
    out = capsys.readouterr().out
    assert "jax" in out and "Light Stage X" in out and "bundled mesh" in out and "shared data" in out


def test_simulate_noise_and_camera_file(tmp_path):
    """Two cameras from a cameras.json give a two-view capture; --noise EXPOSURE
    adds Poisson shot noise whose variance, in radiance units, is L / EXPOSURE
    (Foi et al. 2008, eq. 1 with no read noise): the measured ratio is 1 within
    15% (about 2000 observations)."""
    import stage

    cams = stage.camera_ring(2, 1300.0, fov_deg=11.0, width=24, height=24, start_deg=-20.0, arc_deg=40.0)
    stage.save_cameras(tmp_path / "cams.json", cams)
    common = ["simulate", "--rig", "dome:42", "--resolution", "12", "--camera", str(tmp_path / "cams.json"), "--quiet"]
    assert main(common + ["--out", str(tmp_path / "clean")]) == 0
    assert main(common + ["--out", str(tmp_path / "noisy"), "--noise", "400", "--seed", "3"]) == 0
    clean, noisy = read_capture(tmp_path / "clean"), read_capture(tmp_path / "noisy")
    assert clean.radiance.shape[0] == 2 and len(clean.cameras) == 2
    assert noisy.metadata["noise"]["exposure"] == 400.0
    ok = clean.valid & noisy.valid
    mean = clean.radiance[ok]
    diff = noisy.radiance[ok] - mean
    bright = mean > 0.02  # away from 0, where the Poisson variance is tiny
    assert bright.sum() > 1000
    ratio = np.mean(diff[bright] ** 2) / np.mean(mean[bright] / 400.0)
    assert 0.85 < ratio < 1.15, ratio


def test_fit_refuses_a_corrupt_envmap_before_fitting(pipeline, tmp_path, capsys):
    _, cap, _, _ = pipeline
    bad = tmp_path / "bad.exr"
    bad.write_bytes(b"not an exr")
    assert main(["fit", str(cap), "--model", "ggx", "--out", str(tmp_path / "o"), "--envmap", str(bad), "--quiet"]) == 1
    assert "bad.exr" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()

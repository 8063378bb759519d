import json

import numpy as np
import pytest

from relight.cli import main


def test_no_command_prints_usage_and_fails(capsys):
    assert main([]) == 2
    assert "usage: relight" in capsys.readouterr().err


def test_unknown_flag_exits_nonzero():
    with pytest.raises(SystemExit) as exc:
        main(["demo", "--no-such-flag"])
    assert exc.value.code == 2


def test_mesh_units_and_scale_are_exclusive(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main(["simulate", "--out", str(tmp_path / "o"), "--units", "cm", "--scale", "2"])
    assert e.value.code == 2 and "not allowed with argument" in capsys.readouterr().err


def test_bad_mesh_scale_names_the_flag(tmp_path, capsys):
    assert main(["simulate", "--out", str(tmp_path / "o"), "--scale", "-1", "--quiet"]) == 1
    assert "--mesh head: mesh: scale must be a positive" in capsys.readouterr().err


def test_missing_envmap_names_the_file(tmp_path, capsys):
    missing = tmp_path / "nowhere.hdr"
    code = main(["demo", "--out", str(tmp_path / "o"), "--envmap", str(missing), "--resolution", "16",
                 "--image-size", "32", "--quiet"])
    assert code == 1
    assert "nowhere.hdr" in capsys.readouterr().err


def test_corrupt_envmap_names_the_file(tmp_path, capsys):
    bad = tmp_path / "bad.exr"
    bad.write_bytes(b"this is not an EXR file")
    code = main(["demo", "--out", str(tmp_path / "o"), "--envmap", str(bad), "--resolution", "16",
                 "--image-size", "32", "--quiet"])
    assert code == 1
    assert "bad.exr" in capsys.readouterr().err


@pytest.mark.slow
def test_demo_end_to_end(demo_output):
    """`relight demo` at a small size (32^2 texels, 1 camera, 48 px, 1% noise;
    conftest's demo_output, the run's one demo, whose page test_view.py checks):
    the textured head with subsurface, the full ladder, truth and fit relit by
    the same renderer. Bars (a 32^2 grid: 9 mm texels, where the mean free path
    is barely identifiable; the full-size numbers are in docs/RESULTS.md):
    albedo median within 5%, normals within 2 degrees, relit PSNR above 20 dB
    (43.7 dB at the default 96^2 and 3 cameras, docs/RESULTS.md), < 5%
    flagged, every number finite, every output written."""
    out = demo_output
    report = json.loads((out / "report.json").read_text())
    e = {name: row["all_seen"] for name, row in report["against_truth"]["errors"].items()}
    assert e["diffuse_albedo_rel"]["median"] < 0.05
    assert e["diffuse_albedo_rel"]["samples"] == report["texels_seen"] > 100
    assert e["normal_deg"]["median"] < 2.0
    assert e["mfp_rel"]["samples"] == 3 * report["texels_seen"]  # texel-channels
    assert "errors" not in report and "deprecated_error_keys" not in report
    assert report["relit_psnr_db"] > 20.0 and report["flagged_fraction"] < 0.05
    assert report["cameras"] == 1 and report["lights"] == 346 and report["noise_relative_at_median"] == 0.01
    assert abs(sum(report["model_fraction"].values()) - 1) < 1e-9
    assert set(report["timings_s"]) >= {"simulate", "fit", "relight"}
    # The peak resident memory after each phase (issue 29: the demo's 5.8 GB went unsaid), non-decreasing.
    peak = [report["peak_rss_mib"][k] for k in ("geometry", "visibility", "simulate", "fit", "relight")]
    assert all(100 < p < 64 * 1024 for p in peak) and peak == sorted(peak), peak
    assert "Peak memory" in (out / "report.md").read_text()
    for name in ("preview.png", "relit_truth.exr", "relit_fit.exr", "maps/albedo.exr", "maps/mean_free_path.exr",
                 "truth/albedo.exr", "truth/mean_free_path.exr", "settings.json", "report.md"):
        assert (out / name).is_file(), name
    assert f"over the {report['texels_seen']} seen texels" in (out / "report.md").read_text()
    from relight.io import read_exr

    albedo = read_exr(out / "maps" / "albedo.exr")
    assert albedo.shape == (32, 32, 3) and np.all(np.isfinite(albedo))
    truth_mfp = read_exr(out / "truth" / "mean_free_path.exr")
    assert truth_mfp.max() > 1.0  # the skin's red mean free path, larger on the nose and ears
    assert not list(out.glob("*.tmp*")), "a temporary file survived"

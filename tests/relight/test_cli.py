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
def test_demo_end_to_end(tmp_path):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--resolution", "48", "--image-size", "64", "--quiet"]) == 0
    report = json.loads((out / "report.json").read_text())
    # Issue 2's bar: albedo within 2% and roughness within 10% (median, noise-free).
    assert report["diffuse_albedo_rel_error_median"] < 0.02
    assert report["roughness_rel_error_median"] < 0.10
    assert report["relit_from_fit_vs_image_based_psnr_db"] > 40.0
    for name in ("albedo.exr", "roughness.exr", "relit_image_based_view.png", "relit_from_fit_view.png",
                 "settings.json", "report.md"):
        assert (out / name).is_file(), name
    from relight.io._exr import read_exr

    albedo = read_exr(out / "albedo.exr")
    assert albedo.shape == (48, 48, 3) and np.all(np.isfinite(albedo))
    assert not list(out.glob("*.tmp*")), "a temporary file survived"

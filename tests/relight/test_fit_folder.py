"""``relight.fitting.fit_folder``, the library call behind ``relight fit``: on a 16 x 16 texel capture under a
42-light dome, it writes the map set and the report the command writes, returns what the command prints, and
refuses the subsurface settings without a subsurface step."""

import json

import numpy as np
import pytest

from relight.cli import main
from relight.envmap import bundled_envmap_path
from relight.fitting import FitFolderResult, FitOptions, fit_folder
from relight.io import read_exr


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    root = tmp_path_factory.mktemp("fit_folder")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("RELIGHT_CACHE_DIR", "off")
        cap, ref = root / "cap", root / "ref"
        assert main(["simulate", "--rig", "dome:42", "--resolution", "16", "--image-size", "32", "--out", str(cap),
                     "--quiet"]) == 0
        assert main(["fit", str(cap), "--model", "ggx", "--out", str(ref), "--quiet", "--no-index"]) == 0
    return cap, ref


def test_fit_folder_writes_what_relight_fit_writes(capture, tmp_path):
    cap, ref = capture
    out = tmp_path / "set"
    out.mkdir()
    calls = []
    options = FitOptions(block=4096, progress=lambda *a: calls.append(a))
    r = fit_folder(cap, out, model="ggx", parts=tmp_path / "parts", options=options, envmap=bundled_envmap_path())
    assert isinstance(r, FitFolderResult) and r.kind == "texel" and r.streamed and r.subsurface is None
    assert r.parts["blocks"] == 1 and r.parts["resumed_blocks"] == 0 and r.scene == out / "scene.xml"
    assert {"read_s", "fit_s", "write_s"} <= set(r.report["timings_s"])
    assert any(c[0].startswith("read") for c in calls) and any(c[0].startswith("fit") for c in calls)
    # The same files as the command's set (less its manifest, settings.json and index.html), the same maps.
    command_only = {"relight-set.json", "settings.json", ".parts"}
    assert {p.name for p in out.iterdir()} == {p.name for p in ref.iterdir()} - command_only
    for name in ("albedo", "specular", "roughness", "normal", "model", "mean_free_path"):
        np.testing.assert_array_equal(read_exr(out / f"{name}.exr"), read_exr(ref / f"{name}.exr"), err_msg=name)
    report = json.loads((out / "report.json").read_text())
    assert report["samples"] == r.report["samples"] == r.surface.num_samples
    assert report["failed_fraction"] == r.report["failed_fraction"] and r.warnings == ()


def test_fit_folder_resumes_its_parts(capture, tmp_path):
    cap, _ = capture
    out = tmp_path / "set"
    out.mkdir()
    fit_folder(cap, out, model="ggx", parts=tmp_path / "parts", options=FitOptions(block=64))
    r = fit_folder(cap, out, model="ggx", parts=tmp_path / "parts", resume=True, options=FitOptions(block=64))
    assert r.parts["fitted_blocks"] == 0 and r.parts["resumed_blocks"] == r.parts["blocks"] == 2


def test_subsurface_settings_need_the_subsurface_step(capture, tmp_path):
    cap, _ = capture
    with pytest.raises(ValueError, match="subsurface only"):
        fit_folder(cap, tmp_path, model="ggx", parts=tmp_path / "parts", eta=1.3)

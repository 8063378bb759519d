"""``relight fit`` streaming from a capture folder or store: --block, --devices, --resume (parts in
OUT/.parts, a changed setting refused), and the persistent compilation cache (RELIGHT_CACHE_DIR), on a
16 x 16 texel sphere-head capture under a 42-light dome (110 seen texels: cameras see the flat triangles)."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from relight.cli import main
from relight.fitting import FitOptions, fit_resumable
from relight.io import SampleSubset, load_texel_capture, open_capture_store, open_texel_capture, read_maps
from tests.helpers import xla_flags

from ._cli_runs import head16, small_index

ROOT = Path(__file__).resolve().parents[2]
MAPS = ("albedo", "specular", "alpha", "normal", "model")
# Another device count splits each vmapped solver chunk differently, which moves float32 rounding by an
# ulp and so a few Levenberg-Marquardt stopping decisions (docs/scaling.md): measured max differences
# 2.7e-5 (albedo), 1.4e-5 (specular), 2.5e-4 (roughness) on this capture; bounds 4-6x that. A texel
# fitted to another texel's data would be off by ~0.1. Another block size changes nothing (every solver
# and shading call keeps its shape): bit for bit.
ATOL = {"albedo": 1e-4, "specular": 5e-5, "alpha": 1.5e-3, "normal": 0.0, "model": 0.0}
BLOCK = 32  # 110 texels: 4 blocks
# The fits here run with --no-index: index.html's sweep is the viewer's (tests/relight/test_view.py), not the
# streaming's, and costs every run seconds.


def _maps(folder):
    tex, _ = read_maps(folder)
    return {k: np.asarray(getattr(tex, k)) for k in MAPS}


def _assert_maps(a, b, atol=None):
    for k in MAPS:
        tol = 0.0 if atol is None else atol[k]
        np.testing.assert_allclose(a[k], b[k], rtol=0, atol=tol, err_msg=k)


def _report(folder):
    return json.loads((Path(folder) / "report.json").read_text())


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    """(folder, store, reference map set fitted from the folder with the default block): the run's shared
    16 x 16 capture and its default fit (tests/relight/_cli_runs.py), and this module's store of it."""
    cap, ref = head16(tmp_path_factory)
    store = tmp_path_factory.mktemp("stream") / "cap.zarr"
    with small_index():
        assert main(["convert", str(cap), str(store), "--quiet"]) == 0
    return cap, store, ref


class _NoRadiance:
    def __getattr__(self, name):
        raise AssertionError("read_mask decoded radiance")


def test_sample_subset_reads_the_loaded_texels(captures):
    """open_texel_capture's lazy view reads what load_texel_capture loads, for any slice, from a folder
    and a store; a store's read_mask touches only the mask array."""
    cap, store, _ = captures
    for src in (cap, store):
        whole = load_texel_capture(src)
        lazy = open_texel_capture(src)
        assert isinstance(lazy.capture, SampleSubset) and lazy.capture.shape == tuple(whole.capture.radiance.shape)
        assert np.array_equal(np.asarray(lazy.surface.texel_index), np.asarray(whole.surface.texel_index))
        rad, mask = np.asarray(whole.capture.radiance), np.asarray(whole.capture.mask)
        for sl in (slice(None), slice(0, 1), slice(17, 90), slice(100, 110)):
            r, m = lazy.capture.read(samples=sl)
            assert r.dtype == np.float32 and np.array_equal(r, rad[:, :, sl]) and np.array_equal(m, mask[:, :, sl])
            assert np.array_equal(lazy.capture.read_mask(samples=sl), mask[:, :, sl])
    s = open_capture_store(store)
    full = s.read()[1]
    s._radiance = _NoRadiance()
    assert np.array_equal(s.read_mask(samples=slice(5, 200)), full[:, :, 5:200])
    sub = SampleSubset(s, open_texel_capture(store).capture.index)  # the view's read_mask: no radiance either
    loaded = np.asarray(load_texel_capture(store).capture.mask)
    assert np.array_equal(sub.read_mask(samples=slice(3, 50)), loaded[:, :, 3:50])
    with pytest.raises(ValueError, match="increasing"):
        SampleSubset(s, [3, 3, 4])


def test_store_equals_folder_and_streams(captures, tmp_path):
    cap, store, ref = captures
    out = tmp_path / "o"
    assert main(["fit", str(store), "--model", "ggx", "--out", str(out), "--quiet", "--no-index"]) == 0
    # The same float32 radiance and mask read through another container: the same fit, bit for bit.
    _assert_maps(_maps(out), _maps(ref))
    settings = json.loads((out / "settings.json").read_text())["resolved"]
    assert settings["streamed"] is True and settings["block"] == 4096
    rep = _report(out)
    assert rep["samples"] == 110 and rep["parts"]["blocks"] == 1 and rep["parts"]["fitted_blocks"] == 1


def test_block_size_gives_the_same_maps(captures, tmp_path):
    cap, _, ref = captures
    out = tmp_path / "o"
    assert main(["fit", str(cap), "--model", "ggx",
                 "--out", str(out), "--block", str(BLOCK), "--quiet", "--no-index"]) == 0
    _assert_maps(_maps(out), _maps(ref))
    rep = _report(out)
    assert rep["parts"]["blocks"] == 4 and rep["parts"]["fitted_blocks"] == 4
    assert sorted(p.name for p in (out / ".parts").glob("part_*.npz")) == [
        "part_0_32.npz", "part_32_64.npz", "part_64_96.npz", "part_96_110.npz"]


class _Killed(Exception):
    pass


def test_resume_after_an_interruption_refits_only_the_rest(captures, tmp_path):
    cap, store, _ = captures
    whole = tmp_path / "whole"
    assert main(["fit", str(store), "--model", "ggx",
                 "--out", str(whole), "--block", str(BLOCK), "--quiet", "--no-index"]) == 0
    # A run killed after its second block: what `relight fit --block 32` would have left in OUT/.parts.
    out = tmp_path / "o"
    c, surface, _, _ = open_texel_capture(store)
    done = []

    def stop_after_two(s, e, _):
        done.append((s, e))
        if len(done) == 2:
            raise _Killed

    with pytest.raises(_Killed):
        fit_resumable(c, surface, out / ".parts", model="ggx", solver="lm",
                      options=FitOptions(block=BLOCK, on_block=stop_after_two))
    assert len(list((out / ".parts").glob("part_*.npz"))) == 2
    assert main(["fit", str(store), "--model", "ggx",
                 "--out", str(out), "--block", str(BLOCK), "--resume", "--quiet", "--no-index"]) == 0
    rep = _report(out)["parts"]
    assert (rep["blocks"], rep["resumed_blocks"], rep["fitted_blocks"]) == (4, 2, 2)
    _assert_maps(_maps(out), _maps(whole))  # resumed = uninterrupted, bit for bit (same block, same shapes)
    # Finished: a second --resume fits nothing and writes the same maps.
    assert main(["fit", str(store), "--model", "ggx",
                 "--out", str(out), "--block", str(BLOCK), "--resume", "--quiet", "--no-index"]) == 0
    rep = _report(out)["parts"]
    assert (rep["resumed_blocks"], rep["fitted_blocks"]) == (4, 0)
    _assert_maps(_maps(out), _maps(whole))


def test_resume_refuses_a_changed_setting_and_a_fresh_run_restarts(captures, tmp_path, capsys):
    cap, _, _ = captures
    out = tmp_path / "o"
    assert main(["fit", str(cap), "--model", "ggx",
                 "--out", str(out), "--block", str(BLOCK), "--quiet", "--no-index"]) == 0
    before = _maps(out)
    capsys.readouterr()
    for changed in (["--block", "16"], ["--block", str(BLOCK), "--model", "lambert"]):
        assert main(["fit", str(cap), "--model", "ggx",
                     "--out", str(out), "--resume", "--quiet", "--no-index", *changed]) == 1
        err = capsys.readouterr().err
        assert "--resume" in err and "another fit" in err and "without --resume" in err, err
        _assert_maps(_maps(out), before)  # the refused run wrote nothing
    # Without --resume the parts are cleared and every block is fitted under the new setting.
    assert main(["fit", str(cap), "--model", "ggx", "--out", str(out), "--block", "16", "--quiet", "--no-index"]) == 0
    rep = _report(out)["parts"]
    assert (rep["blocks"], rep["resumed_blocks"], rep["fitted_blocks"]) == (7, 0, 7)
    assert len(list((out / ".parts").glob("part_*.npz"))) == 7


def test_parts_folder_that_is_not_ours_is_not_deleted(captures, tmp_path, capsys):
    cap, _, _ = captures
    out = tmp_path / "o"
    (out / ".parts").mkdir(parents=True)
    (out / ".parts" / "notes.txt").write_text("mine")
    assert main(["fit", str(cap), "--model", "ggx", "--out", str(out), "--quiet"]) == 1
    assert "refusing to delete" in capsys.readouterr().err
    assert (out / ".parts" / "notes.txt").read_text() == "mine"


def test_bad_block_and_devices_flags(captures, tmp_path, capsys):
    cap, _, _ = captures
    assert main(["fit", str(cap), "--model", "ggx", "--out", str(tmp_path / "o"), "--block", "0", "--quiet"]) == 1
    assert "--block 0" in capsys.readouterr().err
    assert main(["fit", str(cap), "--model", "ggx", "--out", str(tmp_path / "o"), "--devices", "64", "--quiet"]) == 1
    assert "--devices 64" in capsys.readouterr().err
    assert main(["fit", str(cap), "--model", "ggx", "--out", str(tmp_path / "o"), "--devices", "some", "--quiet"]) == 1
    assert "--devices some" in capsys.readouterr().err


def _python(code, env_extra, timeout=300):
    """Run ``code`` in a fresh Python (this environment without RELIGHT_CACHE_DIR, the test run's XLA_FLAGS
    (tests.helpers.xla_flags), plus ``env_extra``); its last stdout line parsed as JSON."""
    env = {k: v for k, v in os.environ.items() if k != "RELIGHT_CACHE_DIR"} | {"XLA_FLAGS": xla_flags()}
    env.update(PYTHONPATH=str(ROOT), **env_extra)
    r = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=env, capture_output=True, text=True,
                       timeout=timeout, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


# Runs `relight` in a fresh process once per (environment update, argv) in RUNS, in order, and prints the
# device count and, per run, the persistent cache's event counts during that run.
_COUNTED = """
    import json, os
    import jax
    import jax.monitoring as m
    counts = {}
    def on_event(name, **kw):
        counts[name] = counts.get(name, 0) + 1
    def on_duration(name, secs, **kw):
        counts[name] = counts.get(name, 0) + 1
    m.register_event_listener(on_event)
    m.register_event_duration_secs_listener(on_duration)
    from relight.cli import main
    got = {"devices": len(jax.local_devices()), "runs": []}
    for env, argv in RUNS:
        os.environ.update(env)
        before = dict(counts)
        assert main(argv) == 0, argv
        key = lambda k: counts.get("/jax/compilation_cache/" + k, 0) - before.get("/jax/compilation_cache/" + k, 0)
        got["runs"].append({"hits": key("cache_hits"), "misses": key("cache_misses"),
                            "requests": key("compile_requests_use_cache"),
                            "compiles": counts.get("/jax/core/compile/backend_compile_duration", 0)
                            - before.get("/jax/core/compile/backend_compile_duration", 0)})
    print(json.dumps(got))
"""


def _counted_runs(runs, env):
    return _python(_COUNTED.replace("RUNS", repr(runs)), env)


def _counted(argv, env):
    return _counted_runs([({}, argv)], env)["runs"][0]


@pytest.fixture(scope="module")
def two_devices(captures, tmp_path_factory):
    """One fresh process (two host devices, the compilation cache off) fitting the capture twice: --devices 1
    with the cache off by RELIGHT_CACHE_DIR=off, then --devices 2 with it off by --cache-dir, which beats
    RELIGHT_CACHE_DIR (set to a folder for that run); XDG_CACHE_HOME (the default cache's parent) names a
    folder too. The two runs compile different programs (one device, two), so each compiles. (root, the
    subprocess's counts)."""
    cap, _, _ = captures
    root = tmp_path_factory.mktemp("devices")
    fit = ["fit", str(cap), "--model", "ggx",
           "--quiet", "--no-index"]  # no index.html: its sweep is not what these runs test
    runs = [({}, [*fit, "--devices", "1", "--out", str(root / "d1")]),
            ({"RELIGHT_CACHE_DIR": str(root / "named")}, ["--cache-dir", "off", *fit, "--devices", "2",
                                                          "--out", str(root / "d2")])]
    got = _counted_runs(runs, {"XLA_FLAGS": xla_flags("--xla_force_host_platform_device_count=2"),
                               "RELIGHT_CACHE_DIR": "off", "XDG_CACHE_HOME": str(root / "xdg")})
    return root, got


def test_two_devices_equal_one(two_devices):
    root, got = two_devices
    assert got["devices"] == 2
    assert _report(root / "d2")["parts"]["devices"] == 2
    _assert_maps(_maps(root / "d2"), _maps(root / "d1"), ATOL)


def test_compile_cache_is_written_then_hit(captures, tmp_path):
    cap, _, _ = captures
    # --no-index: the fit's own programs only (index.html's sweep, at the commands' full size in a fresh
    # process, would add render programs and seconds, and is not what the cache is tested with).
    argv = ["fit", str(cap), "--model", "ggx",
            "--out", str(tmp_path / "o"), "--model", "lambert", "--quiet", "--no-index"]
    xdg = tmp_path / "xdg"
    # Default location: $XDG_CACHE_HOME/relight/jax (RELIGHT_CACHE_DIR unset).
    first = _counted(argv, {"XDG_CACHE_HOME": str(xdg)})
    cache = xdg / "relight" / "jax"
    entries = [p for p in cache.iterdir() if p.is_file()]
    # Every compile goes through the cache; a program compiled twice in one process is a hit the second time.
    assert first["requests"] == first["compiles"] and first["misses"] > 0 and len(entries) == first["misses"], first
    # A second process, the folder named by RELIGHT_CACHE_DIR: every program comes from the cache.
    second = _counted(argv, {"RELIGHT_CACHE_DIR": str(cache)})
    assert second["misses"] == 0 and second["hits"] == second["requests"] == first["requests"], (first, second)


@pytest.mark.parametrize("how", ["env", "flag"])
def test_cache_off_writes_nothing(two_devices, how):
    """The two_devices runs: RELIGHT_CACHE_DIR=off ("env"), and --cache-dir off beating RELIGHT_CACHE_DIR set
    to a folder ("flag")."""
    root, got = two_devices
    run = got["runs"][["env", "flag"].index(how)]
    # JAX still asks (requests), but with no cache folder nothing is looked up (no miss) or found (no hit).
    assert run["compiles"] > 0 and run["misses"] == 0 and run["hits"] == 0, run
    assert not (root / "xdg").exists() and not (root / "named").exists()

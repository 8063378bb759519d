"""SIGKILL during `relight simulate`, `relight fit` and `relight render`
re-running into an existing result set: the output folder is always the
complete old set, the complete new set, or absent (never a mix), the readers
reject a mix, and the next run cleans up what the killed one left.

The kills are deterministic: each command runs in a subprocess (``_WRAPPER``)
that injects a hook into the result-set writer (``relight.results._resultset``'s
``_on_step``, called at every ``relight.results.commit_point``) before it calls
``relight.cli.main``; the hook SIGKILLs the process at the named point: "built"
(every file written in the temporary folder, no manifest), "manifest"
(manifest written, not swapped in), "moved" (the two-rename swap, forced by
setting ``_exchange_allowed`` to False: the old set moved aside, the new one
not yet in) and "swapped" (the new set in place, the old one not yet deleted).
The library itself holds no test hook.
`relight fit` is also killed at "block" (its first block written to
OUT/.parts, the map set not yet touched). Only the runs that are killed need a process of their own: the
runs that complete (the old sets, and the runs after a kill that clean up) run in the test's process.
Tiny inputs (an 8 x 8 texel grid, 42 lights) and the test run's one persistent compilation cache
(tests/conftest.py, shared with the in-process runs) keep each subprocess to seconds."""

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from relight.io import ImageFormatError, open_capture, read_exr, read_maps
from relight.results import ResultSetError, open_result_set
from relight.results._resultset import _set_files
from tests.helpers import xla_flags

# `relight ARGS...` with the test hooks injected: argv = [kill point or "", "1" for the two-rename swap, ARGS...].
_WRAPPER = """
import os, signal, sys
from relight.results import _resultset
point, no_exchange = sys.argv[1], sys.argv[2] == "1"
def kill_at(name):
    if name == point:
        os.kill(os.getpid(), signal.SIGKILL)
if point:
    _resultset._on_step = kill_at
if no_exchange:
    _resultset._exchange_allowed = False
from relight.cli import main
sys.exit(main(sys.argv[3:]))
"""
# --no-index: the sets' index pages (tests/relight/test_view.py) would be most of each run's time.
SIM = ["simulate", "--rig", "dome:42", "--resolution", "8", "--image-size", "16", "--no-index", "--quiet"]
FIT = ["--model", "lambert", "--block", "8", "--no-index", "--quiet"]
# A killed run is given this long at most (it dies at its kill point long before).
RUN_TIMEOUT_S = 180


@pytest.fixture(scope="module")
def env():
    # The run's RELIGHT_CACHE_DIR (tests/conftest.py) is kept: the subprocesses read what the in-process runs
    # compiled.
    return os.environ | {"XLA_FLAGS": xla_flags(), "JAX_PLATFORMS": "cpu"}


def _run(env, args, kill_at=None, no_exchange=False):
    """``relight ARGS`` killed at ``kill_at`` in a subprocess; without a kill point, run to completion in this
    process (nothing to kill, so no process of its own is needed)."""
    if kill_at is None and not no_exchange:
        from relight.cli import main

        assert main(args) == 0
        return
    argv = [sys.executable, "-c", _WRAPPER, kill_at or "", "1" if no_exchange else "0", *args]
    r = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=RUN_TIMEOUT_S)
    assert r.returncode == -signal.SIGKILL, (kill_at, r.returncode, r.stderr[-2000:])


def _state(folder: Path, kind: str, old_generation: str | None, new_flags: dict) -> str:
    """'absent', 'old' or 'new'; any other state fails the test. A set must verify file by file against its
    manifest and hold no file the manifest does not list."""
    if not folder.exists():
        return "absent"
    visible = [p for p in folder.iterdir() if not p.name.startswith(".")]
    if not visible:
        return "absent"  # a fit's folder holding only its resumable .parts: no result set
    rs = open_result_set(folder, kind)
    rs.check()
    assert set(_set_files(folder, rs.manifest["unhashed"])) == set(rs.files), "files the manifest does not list"
    if rs.generation == old_generation:
        return "old"
    flags = json.loads((folder / "settings.json").read_text())["flags"]
    assert all(flags[k] == v for k, v in new_flags.items()), ("neither the old set nor the new one", flags)
    return "new"


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.parent.iterdir() if p.name.startswith(f".{folder.name}."))


@pytest.fixture(scope="module")
def capture(tmp_path_factory, env):
    root = tmp_path_factory.mktemp("kill")
    _run(env, [*SIM, "--out", str(root / "cap")])
    return root


def test_simulate_killed_while_replacing_a_capture(capture, env):
    root = capture
    sim = root / "sim"
    shutil.copytree(root / "cap", sim)  # the complete old capture
    old = open_result_set(sim, "simulate").generation
    new = [*SIM, "--seed", "7", "--noise", "100", "--out", str(sim)]
    new_flags = {"seed": 7, "noise": "100"}
    # The two-rename swap killed between its renames: no capture at all, never half of one.
    _run(env, new, kill_at="moved", no_exchange=True)
    assert _state(sim, "simulate", old, new_flags) == "absent"
    # Left: the old set moved aside, the new one's temporary folder, and the dead writer's (stale) lock file.
    assert [n.rsplit(".", 1)[1] for n in _leftovers(sim)] in (["tmp", "old", "lock"], ["old", "tmp", "lock"])
    # The next run puts the old set back, deletes every leftover and replaces it whole.
    _run(env, new)
    assert _state(sim, "simulate", old, new_flags) == "new"
    assert _leftovers(sim) == []
    assert (sim.stat().st_mode & 0o777) == 0o777 & ~_umask()  # the umask's mode, not mkdtemp's 0o700
    reader = open_capture(sim)
    assert reader.shape[1] == 42


def _umask() -> int:
    from relight.results._atomic import _umask as umask

    return umask()


def test_fit_killed_while_replacing_a_map_set(capture, env):
    root = capture
    out = root / "maps"
    _run(env, ["fit", str(root / "cap"), "--model", "ggx", "--out", str(out), *FIT])
    old = open_result_set(out, "fit").generation
    blocks = json.loads((out / "report.json").read_text())["parts"]["blocks"]
    assert blocks > 1
    old_albedo = read_maps(out)[0].albedo
    snapshot = root / "maps_old"
    shutil.copytree(out, snapshot)
    new = ["fit", str(root / "cap"), "--model", "ggx", "--out", str(out), "--solver", "gn", *FIT]
    new_flags = {"solver": "gn"}

    # Killed after the new run's first block (the reported failure: a new albedo.exr beside the old maps.json
    # and the old specular / roughness). The old set stands; the block is kept for --resume.
    _run(env, new, kill_at="block")
    assert len(list((out / ".parts").glob("part_*.npz"))) == 1  # the new run cleared the old parts first
    assert _state(out, "fit", old, new_flags) == "old"
    np.testing.assert_array_equal(read_maps(out)[0].albedo, old_albedo)

    # Manifest written in the temporary set, not swapped in: still the old set.
    _run(env, new, kill_at="manifest")
    assert _state(out, "fit", old, new_flags) == "old" and _leftovers(out)

    # Completed: the new set, nothing left over; its blocks stay resumable in .parts.
    _run(env, new)
    assert _state(out, "fit", old, new_flags) == "new"
    assert _leftovers(out) == [] and len(list((out / ".parts").glob("part_*.npz"))) == blocks
    read_maps(out)

    # A mix of the two (what an in-place writer killed mid-set left): the new maps.json (its fit_options say
    # gn) beside the old maps. Every file is valid on its own; the set is refused.
    shutil.copy(out / "maps.json", snapshot / "maps.json")
    with pytest.raises(ImageFormatError, match=r"maps\.json: differs .* mixed") as err:
        read_maps(snapshot)
    assert isinstance(err.value.__cause__, ResultSetError)


def test_render_killed_while_replacing_its_images(capture, env):
    root = capture
    out = root / "relit"
    _run(env, ["render", str(root / "cap"), "--out", str(out), "--image-size", "16", "--no-index", "--quiet"])
    old = open_result_set(out, "render").generation
    new = ["render", str(root / "cap"), "--out", str(out), "--image-size", "16", "--rotate", "90", "--no-index",
           "--quiet"]
    new_flags = {"rotate": 90.0}
    # Swapped in, the old set not yet deleted: the new set, whole.
    _run(env, new, kill_at="swapped")
    assert _state(out, "render", old, new_flags) == "new" and _leftovers(out)
    assert np.all(np.isfinite(read_exr(out / "relit.exr")))
    # Killed again with every file of a newer set written but no manifest: the (now old) set stands.
    newer = [*new[:-4], "--rotate", "180", "--no-index", "--quiet"]
    _run(env, newer, kill_at="built")
    assert _state(out, "render", open_result_set(out).generation, {"rotate": 180.0}) == "old"
    assert np.all(np.isfinite(read_exr(out / "relit.exr")))

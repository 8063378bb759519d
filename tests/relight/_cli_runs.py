"""CLI runs that several test modules read, built once per test run.

``relight simulate --rig dome:42 --resolution 16 --image-size 32`` (the bundled head, one 32 px camera) and the
default ``relight fit`` of it are the inputs of test_cli_pipeline, test_cli_fit_stream, test_cli_simulate_store
and test_cli_render_outputs. Each used to build its own copy; :func:`head16` builds one for the run, in the
run's temporary folder under a file lock (as tests/conftest.py's demo_output does), so xdist workers share it
too. The folders are read-only for the tests: a test that changes one copies it first."""

from __future__ import annotations

import contextlib
import importlib
from pathlib import Path

import pytest

from tests.helpers import locked, run_root

HEAD16_SIMULATE = ["simulate", "--rig", "dome:42", "--resolution", "16", "--image-size", "32", "--quiet"]


@contextlib.contextmanager
def small_index():
    """conftest's 2-frame, 32 px index sweep (its autouse _small_index_pages) for module- and session-scoped
    fixtures, which pytest sets up before any function-scoped autouse fixture; ``convert`` too."""
    with pytest.MonkeyPatch.context() as mp:
        for name in ("simulate", "fit", "render", "demo", "convert"):
            module = importlib.import_module(f"relight.cli.{name}")
            mp.setattr(module, "INDEX_FRAMES", 2)
            mp.setattr(module, "INDEX_SIZE", 32)
        yield


def head16(tmp_path_factory) -> tuple[Path, Path]:
    """(capture folder, map set): HEAD16_SIMULATE and ``relight fit CAPTURE --quiet``, once per run."""
    from relight.cli import main

    root = run_root(tmp_path_factory) / "shared-head16"
    cap, maps = root / "capture", root / "maps"
    with locked(run_root(tmp_path_factory) / "shared-head16.lock"):
        if not (maps / "report.json").is_file():
            with small_index():
                assert main([*HEAD16_SIMULATE, "--out", str(cap)]) == 0
                assert main(["fit", str(cap), "--model", "ggx", "--out", str(maps), "--quiet"]) == 0
    return cap, maps

"""Strict test settings (after optimistix's conftest): float64 available for the
mathematics, rank promotion raises, dtype promotion is strict (no silent float32 ->
float64 or int -> float mixing), warnings are errors, and every function in brdf,
skin_bssrdf, stage and relight has its jaxtyping annotations checked at call time
(pyproject's --jaxtyping-packages, with the checker in tests/helpers.py)."""

import importlib.util
import os
import shutil
import tempfile
from pathlib import Path

import jax
import pytest

import tests.helpers  # the --jaxtyping-packages checker (tests.helpers.typechecker) must be loaded first

# One persistent compilation cache for the whole run, shared by the xdist workers and the CLI subprocesses, in a
# fresh temporary folder (never the user's ~/.cache/relight/jax; tests of the cache set their own): the suite
# compiles many identical programs (the same fit, simulate and render shapes from different tests), and XLA's CPU
# compile is most of its time. A cache hit returns the executable XLA would have built; nothing else changes.
# XLA's CPU flags of the run (tests.helpers.TEST_XLA_FLAGS: faster compiles), set before JAX starts its backend.
os.environ["XLA_FLAGS"] = " ".join(x for x in (os.environ.get("XLA_FLAGS", ""), tests.helpers.TEST_XLA_FLAGS) if x)
_RUN = os.environ.get("PYTEST_XDIST_TESTRUNUID") or f"pid{os.getpid()}"
TEST_CACHE_DIR = Path(tempfile.gettempdir()) / f"relight-test-jax-cache-{_RUN}"
os.environ.setdefault("RELIGHT_CACHE_DIR", str(TEST_CACHE_DIR))
jax.config.update("jax_compilation_cache_dir", os.environ["RELIGHT_CACHE_DIR"])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")
jax.config.update("jax_numpy_dtype_promotion", "strict")

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture
def key():
    return jax.random.PRNGKey(5678)


@pytest.fixture
def shared_data():
    """Path to ../shared/data; skips the test with a reason when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data not found at {SHARED_DATA} (real-data tests need ../shared/data)")
    return SHARED_DATA


@pytest.fixture(autouse=True)
def _small_index_pages(request, monkeypatch):
    """Every command still writes its index.html (inside its result set, listed in the manifest), but outside the
    viewer's own tests with a 2-frame, 32 px rotation sweep and no 3D view: the page itself, at the commands' 12
    frames and with its 3D view, is tested in tests/relight/test_view.py, and the full page in every CLI test
    would cost the suite minutes."""
    if request.module.__name__.rsplit(".", 1)[-1] == "test_view":
        return
    import importlib

    for name in ("simulate", "fit", "render", "demo"):
        module = importlib.import_module(f"relight.cli.{name}")
        monkeypatch.setattr(module, "INDEX_FRAMES", 2)
        monkeypatch.setattr(module, "INDEX_SIZE", 32)
    # The 3D view's section too (its environment precomputation costs 5-10 s in a fresh process): tested there.
    monkeypatch.setattr(importlib.import_module("relight.view._page"), "VIEW3D", False)


# The demo both tests/relight/test_cli.py (its physics) and tests/relight/test_view.py (its index.html) check:
# `relight demo` at 32^2 texels, 1 camera (the fit of several views: test_photo_texels.py), 48 px, built once for
# the run by demo_output.
DEMO_ARGV = ["demo", "--resolution", "32", "--cameras", "1", "--image-size", "48", "--quiet"]


@pytest.fixture(scope="session")
def demo_output(tmp_path_factory):
    """The folder of one ``relight demo`` (DEMO_ARGV) with its full index page (the commands' 12 frames at
    128 px, as test_view checks it): built once per run and shared by test_cli.py and test_view.py, which
    only read it. Under xdist the workers share it too: the first to ask builds it under a file lock in the
    run's temporary folder, the other waits and reads it (a demo costs about two minutes of CPU)."""
    from relight.cli import _flags, demo, main

    root = tests.helpers.run_root(tmp_path_factory)
    out = root / "shared-demo"
    with tests.helpers.locked(root / "shared-demo.lock"):
        if not (out / "report.json").is_file():
            with pytest.MonkeyPatch.context() as mp:  # the commands' own index page, whatever a test patched
                mp.setattr(demo, "INDEX_FRAMES", _flags.INDEX_FRAMES)
                mp.setattr(demo, "INDEX_SIZE", _flags.INDEX_SIZE)
                mp.setattr(importlib.import_module("relight.view._page"), "VIEW3D", True)
                assert main([*DEMO_ARGV, "--out", str(out)]) == 0
    return out


if importlib.util.find_spec("xdist") is not None:

    def pytest_xdist_make_scheduler(config, log):
        """``-n N`` schedules by work stealing instead of xdist's default ``load``: each worker starts on one
        contiguous half of the collection and steals from the end of another's queue when it runs dry. ``load``
        hands out many small consecutive chunks, so the tests of one module land on both workers and the
        module-scoped fixtures (simulated captures, CLI runs) are built twice; work stealing splits a module
        only at a steal. An explicit ``--dist`` other than ``load`` is left alone."""
        if config.getvalue("dist") != "load":
            return None
        from xdist.scheduler import WorkStealingScheduling

        return WorkStealingScheduling(config, log)


def pytest_sessionfinish(session):
    """The run's compilation cache goes with the run (the controller removes it; workers have workerinput)."""
    if not hasattr(session.config, "workerinput") and os.environ.get("RELIGHT_CACHE_DIR") == str(TEST_CACHE_DIR):
        shutil.rmtree(TEST_CACHE_DIR, ignore_errors=True)

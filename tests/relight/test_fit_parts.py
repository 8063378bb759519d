"""relight.fitting.fit_parts / merge_parts: a fit written block by block as parts of one result set,
resumed after an interruption, split over processes (jax.distributed on CPU), and merged: always the
Fit of one relight.fit call with the same block, bit for bit; a set of another fit is refused."""

import dataclasses
import json
import os
import socket
import subprocess
import sys
import textwrap
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

import stage
from relight import fit
from relight.fitting import FitOptions, PartsFingerprintError, PartsIncompleteError, fit_parts, merge_parts
from tests.helpers import xla_flags

from ..scenes import noisy_ggx_sphere

ROOT = Path(__file__).resolve().parents[2]
FIELDS = ("rho_d", "rho_s", "alpha", "normal", "tangent", "model", "residual", "heldout", "result", "steps",
          "observed", "uncertainty")
# Few, short LM rounds: the test is of bookkeeping, not of convergence. The chunk and steps of
# test_fit_stream.py's FAST on the same sphere: the same compiled solver programs (tests/conftest.py's cache).
FAST = FitOptions(chunk=16, rounds=2, steps_per_round=6)
BLOCK = 24


def _scene(seed=0):
    """A noisy GGX sphere, one camera, a 42-light dome (~80 texels); deterministic (also built, the same
    bytes, in each subprocess of the two-process test)."""
    return noisy_ggx_sphere(res=16, seed=seed)


@pytest.fixture(scope="module")
def scene():
    return _scene()


@pytest.fixture(scope="module")
def reference(scene):
    cap, surface = scene
    return fit(cap, surface, model="ggx", loss="cauchy", options=dataclasses.replace(FAST, block=BLOCK))


def _assert_same(a, b, atol=0.0):
    """Every per-sample field equal (atol 0: bit for bit), and the static fields."""
    for k in FIELDS:
        x, y = np.asarray(getattr(a, k)), np.asarray(getattr(b, k))
        assert x.dtype == y.dtype and x.shape == y.shape, k
        if atol == 0.0:
            assert np.array_equal(x, y), (k, float(np.max(np.abs(x - y))))
        else:
            np.testing.assert_allclose(x, y, rtol=0, atol=atol, err_msg=k)
    assert a.alpha_floor == b.alpha_floor and a.solver == b.solver


class _Killed(Exception):
    pass


def test_resumed_equals_uninterrupted_equals_fit(scene, reference, tmp_path):
    """Interrupted after its first block (an exception from on_block, as a kill would leave it: the
    first part written, no other), then resumed: the resumed run fits only the other blocks, and both
    sets merge to relight.fit's result bit for bit (a solver padding one observation more differs at
    4e-15: bit-identity is a real check). A rerun of a finished set fits nothing; a deleted or
    truncated part is refused by merge and refitted alone."""
    cap, surface = scene
    P = surface.num_samples
    n_blocks = -(-P // BLOCK)
    assert n_blocks >= 3

    whole = fit_parts(cap, surface, tmp_path / "whole", model="ggx", loss="cauchy", block=BLOCK, options=FAST)
    assert sorted(p.name for p in whole.glob("part_*.npz")) == sorted(
        f"part_{s}_{min(s + BLOCK, P)}.npz" for s in range(0, P, BLOCK))
    _assert_same(merge_parts(whole, surface), reference)

    def kill(start, stop, arrays):
        raise _Killed(start)

    with pytest.raises(_Killed):
        fit_parts(cap, surface, tmp_path / "cut", model="ggx", loss="cauchy", block=BLOCK, on_block=kill, options=FAST)
    assert [p.name for p in (tmp_path / "cut").glob("part_*.npz")] == [f"part_0_{BLOCK}.npz"]
    with pytest.raises(PartsIncompleteError, match=f"{n_blocks - 1} of {n_blocks} blocks"):
        merge_parts(tmp_path / "cut", surface)
    done = []
    fit_parts(cap, surface, tmp_path / "cut", model="ggx", loss="cauchy",
              block=BLOCK, on_block=lambda s, e, a: done.append((s, e)), options=FAST)
    assert [s for s, _ in done] == list(range(BLOCK, P, BLOCK))
    _assert_same(merge_parts(tmp_path / "cut", surface), reference)

    # A finished set: no block fitted, no progress reported.
    calls = []
    fit_parts(cap, surface, whole, model="ggx", loss="cauchy", block=BLOCK, on_block=lambda *a: calls.append(a),
              options=dataclasses.replace(FAST, progress=lambda *a: calls.append(a)))
    assert calls == []

    # A deleted part: refused by merge, then refitted alone.
    (whole / f"part_{BLOCK}_{2 * BLOCK}.npz").unlink()
    with pytest.raises(PartsIncompleteError, match=f"{BLOCK}..{2 * BLOCK}"):
        merge_parts(whole, surface)
    fit_parts(cap, surface, whole, model="ggx", loss="cauchy",
              block=BLOCK, on_block=lambda s, e, a: calls.append((s, e)), options=FAST)
    assert calls == [(BLOCK, 2 * BLOCK)]
    _assert_same(merge_parts(whole, surface), reference)

    # A truncated part (not written by fit_parts, whose writes are atomic): refused, then refitted.
    last = whole / f"part_{(n_blocks - 1) * BLOCK}_{P}.npz"
    last.write_bytes(last.read_bytes()[:100])
    with pytest.raises(PartsFingerprintError, match="unreadable"):
        merge_parts(whole, surface)
    calls.clear()
    fit_parts(cap, surface, whole, model="ggx", loss="cauchy",
              block=BLOCK, on_block=lambda s, e, a: calls.append((s, e)), options=FAST)
    assert calls == [((n_blocks - 1) * BLOCK, P)]
    _assert_same(merge_parts(whole, surface), reference)


def test_another_fit_is_refused(scene, tmp_path):
    """A folder holding another fit's set (other settings, other radiance, another block size) is
    refused by fit_parts unless overwrite=True; a foreign part slipped into a set, or another surface,
    is refused by merge_parts."""
    cap, surface = scene
    P = surface.num_samples
    block = P  # one block: the cheapest set
    a = fit_parts(cap, surface, tmp_path / "a", model="ggx", loss="cauchy", block=block, options=FAST)
    with pytest.raises(PartsFingerprintError, match="another fit"):
        fit_parts(cap, surface, a, model="ggx", loss="cauchy", block=block, options=FAST, cauchy=0.2)
    with pytest.raises(PartsFingerprintError, match="another fit"):
        fit_parts(cap, surface, a, model="ggx", loss="cauchy", block=block - 1, options=FAST)
    rad = np.asarray(cap.radiance).copy()
    rad[0, 3, P - 1, 1] *= 1.0 + 1e-6  # one value of the last sample, changed by one part in a million
    other = stage.Capture(jnp.asarray(rad), cap.mask, cap.rig, cap.cameras)
    with pytest.raises(PartsFingerprintError, match="another fit"):
        fit_parts(other, surface, a, model="ggx", loss="cauchy", block=block, options=FAST)
    # The same settings: accepted, nothing refitted.
    calls = []
    fit_parts(cap, surface, a, model="ggx", loss="cauchy",
              block=block, on_block=lambda *x: calls.append(x), options=FAST)
    assert calls == []

    b = fit_parts(other, surface, tmp_path / "b", model="ggx", loss="cauchy", block=block, options=FAST)
    part = f"part_0_{P}.npz"
    (a / part).write_bytes((b / part).read_bytes())  # b's part under a's manifest
    with pytest.raises(PartsFingerprintError, match=part):
        merge_parts(a, surface)
    moved = surface.subset(np.arange(P))
    moved = stage.Surface(position=moved.position + 1.0, normal=moved.normal, tangent=moved.tangent,
                          bitangent=moved.bitangent, uv=moved.uv, area=moved.area, texel_index=moved.texel_index,
                          face=moved.face, resolution=moved.resolution, barycentric=moved.barycentric)
    with pytest.raises(PartsFingerprintError, match="another surface"):
        merge_parts(b, moved)
    with pytest.raises(ValueError, match="process_index"):
        fit_parts(cap, surface, a, model="ggx", loss="cauchy",
                  block=block, process_index=2, process_count=2, options=FAST)

    # overwrite=True: a's set replaced by other's, and it merges to other's set.
    fit_parts(other, surface, a, model="ggx", loss="cauchy", block=block, overwrite=True, options=FAST)
    _assert_same(merge_parts(a, surface), merge_parts(b, surface))


_WORKER = textwrap.dedent("""
    import sys
    import jax
    jax.config.update("jax_enable_x64", True)  # as tests/conftest.py: the same working float as the test's fit
    sys.path.insert(0, {root!r})
    jax.distributed.initialize("localhost:{port}", num_processes=2, process_id={pid})
    from tests.relight.test_fit_parts import BLOCK, FAST, _scene
    from relight.fitting import fit_parts

    assert (jax.process_index(), jax.process_count()) == ({pid}, 2)
    cap, surface = _scene()
    done = []
    fit_parts(cap, surface, {folder!r}, model="ggx", loss="cauchy",
              block=BLOCK, on_block=lambda s, e, a: done.append(s), options=FAST)
    print("BLOCKS", {pid}, done)
    jax.distributed.shutdown()
""")


def _cache_env() -> dict:
    """The run's persistent compilation cache (tests/conftest.py's $RELIGHT_CACHE_DIR) for a worker process, as
    JAX's own environment settings: a worker then loads the programs this process (or an earlier worker) compiled
    instead of compiling them again. A hit returns the executable XLA would build; nothing else changes."""
    folder = os.environ.get("RELIGHT_CACHE_DIR")
    if not folder or folder.lower() in ("off", "none"):
        return {}
    return dict(JAX_COMPILATION_CACHE_DIR=folder, JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0.2",
                JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES="-1")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def test_two_processes_share_the_blocks(scene, reference, tmp_path):
    """Two local processes joined by jax.distributed.initialize (CPU) each fit their round-robin share
    of the blocks (process_index / process_count from JAX) into one folder; merged here, the set equals
    the single-process relight.fit to 1e-6 (measured: bit for bit)."""
    cap, surface = scene
    P = surface.num_samples
    port = _free_port()
    env = dict(os.environ, JAX_PLATFORMS="cpu", XLA_FLAGS=xla_flags(), **_cache_env())
    procs = [subprocess.Popen([sys.executable, "-c", _WORKER.format(root=str(ROOT), port=port, pid=i,
                                                                    folder=str(tmp_path))],
                              env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for i in range(2)]
    outs = []
    try:
        for p in procs:
            outs.append(p.communicate(timeout=150))
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
    for p, (_, err) in zip(procs, outs, strict=True):
        assert p.returncode == 0, err[-3000:]
    shares = {}
    for out, _ in outs:
        line = [x for x in out.splitlines() if x.startswith("BLOCKS")][-1]
        pid, rest = line.split(" ", 2)[1:]
        shares[int(pid)] = json.loads(rest)
    starts = list(range(0, P, BLOCK))
    assert shares == {0: starts[0::2], 1: starts[1::2]}
    _assert_same(merge_parts(tmp_path, surface), reference, atol=1e-6)

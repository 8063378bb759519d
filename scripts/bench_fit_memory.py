"""Peak memory of relight.fit against the texel count and the block size.

For each texel count N a synthetic capture (a GGX sphere under a 162-light dome,
its ~P0 simulated texels repeated to N) is written once as a capture store
(relight.io.write_capture_store); then each (N, block) is fitted in a fresh
process from the store (``relight.fit(open_capture_store(...), ...)``), which
prints its peak resident set size (``resource.getrusage(RUSAGE_SELF).ru_maxrss``:
a per-process maximum, hence one process per measurement) and the peak of what
Python and NumPy allocate during the fit (tracemalloc: the host-side working
set without JAX's buffers, the allocator's slack and the libraries; steadier
than RSS, whose slack varies by tens of MiB from run to run). ``block = N`` is
the old behaviour (every sample's observations built up front) and the
baseline of each row; "floor" is a fit of one chunk (64 texels: JAX, the
libraries, the compiled solver). RSS ratios are of peak - floor, to the old
behaviour's.

    .venv/bin/python scripts/bench_fit_memory.py                  # N = 2048, 8192, 32768; block 1024, 4096
    .venv/bin/python scripts/bench_fit_memory.py --texels 4096 65536 --blocks 4096 --model auto
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

from _common import load_surface, parser, run_json, save_surface, texel_sphere_capture, tiled

# Samples per store chunk: a divisor of every block measured, so a block read decodes only its own chunks.
STORE_CHUNK = 512


def child(args) -> None:
    """One measurement: fit the store at args.store (its surface beside it) with block args.block, print JSON."""
    import numpy as np

    import relight
    from relight.io import open_capture_store

    store = open_capture_store(args.store)
    surface = load_surface(Path(args.store).with_suffix(".npz"))
    t = time.perf_counter()
    tracemalloc.start()
    f = relight.fit(store, surface, model=args.model,
                    options=relight.fitting.FitOptions(block=args.block, chunk=args.chunk, rounds=args.rounds,
                                                       steps_per_round=args.steps))
    traced = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert np.all(np.isfinite(np.asarray(f.rho_d)))
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # Linux: KiB
    print(json.dumps(dict(peak=peak, traced=traced, seconds=time.perf_counter() - t)))


def prepare(args) -> None:
    """Write the stores (args.out/n<N>.zarr and the floor's, each with its surface beside it); print the scene."""
    from relight.io import write_capture_store

    cap, surface = texel_sphere_capture(args.res)
    for n in [args.chunk, *args.texels]:
        rep = tiled(cap, surface, n)
        store = write_capture_store(Path(args.out) / f"n{n}.zarr", rep[0], chunks=(1, 8, min(n, STORE_CHUNK), 3))
        save_surface(store.with_suffix(".npz"), rep[1])
    V, L, P0, _ = cap.shape
    print(json.dumps(dict(views=V, lights=L, texels=P0)))


def _child_args(args) -> list[str]:
    return ["--res", str(args.res), "--model", args.model, "--chunk", str(args.chunk), "--rounds", str(args.rounds),
            "--steps", str(args.steps)]


def measure(args, store: Path, block: int) -> dict:
    return run_json([sys.executable, __file__, "--child", "--store", str(store), "--block", str(block),
                     *_child_args(args)])


def main(argv=None) -> None:
    p = parser(__doc__)
    p.add_argument("--texels", type=int, nargs="+", default=[2048, 8192, 32768])
    p.add_argument("--blocks", type=int, nargs="+", default=[1024, 4096])
    p.add_argument("--model", default="ggx")
    p.add_argument("--chunk", type=int, default=64)
    p.add_argument("--rounds", type=int, default=1)
    p.add_argument("--steps", type=int, default=3, help="steps per round (memory does not depend on it)")
    p.add_argument("--res", type=int, default=48, help="texel grid of the simulated sphere (P0 distinct texels)")
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--prepare", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--store", help=argparse.SUPPRESS)
    p.add_argument("--out", help=argparse.SUPPRESS)
    p.add_argument("--block", type=int, default=1, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child:
        return child(args)
    if args.prepare:
        return prepare(args)

    # This process imports no JAX and holds no capture: Linux keeps ru_maxrss across fork and exec, so a
    # child's peak would otherwise start at this process's size.
    mib = 1 << 20
    with tempfile.TemporaryDirectory() as tmp:
        scene = run_json([sys.executable, __file__, "--prepare", "--out", tmp, "--texels", *map(str, args.texels),
                      *_child_args(args)])
        print(f"# relight.fit peak RSS; model={args.model} chunk={args.chunk} rounds={args.rounds} "
              f"steps={args.steps}; {scene['views']} view(s), {scene['lights']} lights, {scene['texels']} distinct "
              f"texels repeated to N; read from a capture store")
        print(f"{'N':>7} {'block':>10} {'peak MiB':>9} {'- floor':>8} {'KiB/texel':>9} {'ratio':>6} "
              f"{'numpy MiB':>9} {'ratio':>6} {'s':>6}")
        # The floor: a fit of one chunk (JAX, the libraries, the compiled solver, the capture store's reader).
        floor = measure(args, Path(tmp) / f"n{args.chunk}.zarr", args.chunk)["peak"]
        print(f"{args.chunk:>7} {'floor':>10} {floor / mib:>9.1f}", flush=True)
        for n in args.texels:
            store = Path(tmp) / f"n{n}.zarr"
            base = measure(args, store, n)
            rows = [(n, base)] + [(b, measure(args, store, b)) for b in args.blocks if b < n]
            for b, r in rows:
                extra = r["peak"] - floor
                label = f"{b}" + (" (old)" if b == n else "")
                print(f"{n:>7} {label:>10} {r['peak'] / mib:>9.1f} {extra / mib:>8.1f} {extra / 1024 / n:>9.2f} "
                      f"{extra / max(base['peak'] - floor, 1):>6.2f} {r['traced'] / mib:>9.1f} "
                      f"{r['traced'] / base['traced']:>6.2f} {r['seconds']:>6.1f}", flush=True)


if __name__ == "__main__":
    main()

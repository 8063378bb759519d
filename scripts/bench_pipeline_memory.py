"""Peak memory of the face-scale pipeline: ``relight simulate --out HEAD.zarr``
(the streaming store form) and ``relight.fit`` from that store, on the bundled
head (``stage.load_head``) under the Light Stage X rig (346 lights, the
defaults of ``relight simulate``), at several texel grids.

Every measurement is its own fresh process, which prints its peak resident
set size (``relight.simulation.peak_rss_mib``: ``ru_maxrss``, a per-process
maximum). Each process also splits its peak in two: the peak while the texel
surface is built (``stage.texel_samples`` over the whole grid, which every
command needs first) and, after handing freed heap back
(``relight.simulation.release_freed_memory``: glibc ``malloc_trim``) and
resetting the kernel's high-water mark (``/proc/self/clear_refs`` = 5,
Linux), the peak of the rest: the streamed simulation / the fit. The total is
the larger of the two. The benchmark wraps ``stage.texel_samples`` (which
both build the grid through) to take the first peak and reset it after.

* simulate: ``relight.cli.main(["simulate", "--resolution", N, "--out",
  N.zarr, "--block", B])`` (the CLI itself, ``relight.simulation.simulate_texel_capture``).
* fit: the store opened as ``relight fit`` opens it,
  ``relight.io.open_texel_capture``: the surface rebuilt from its metadata
  (``relight.io.texel_surface``, through ``stage.texel_samples``), the
  texels with a valid observation found from the mask alone (chunk by chunk),
  and the capture a ``relight.io.SampleSubset`` of the store over them (each
  block reads only the store chunks it touches); then
  ``relight.fit(capture, surface, model="ggx", options=FitOptions(rounds=3, block=...))``. Throughput
  excludes compilation:
  the first block (which compiles every solver program) is timed on its own
  (``on_block``), texels/s is over the remaining blocks, and compile time =
  first block's time - its texels / that rate. ``--fit-samples K`` fits only
  the first K seen texels (the store still holds all of them; the working set
  per block is the same), for grids whose full fit would not finish in time
  (a ``SampleSubset`` over the first K of the seen texels).

    .venv/bin/python scripts/bench_pipeline_memory.py                       # 128, 512, 1024
    .venv/bin/python scripts/bench_pipeline_memory.py --sizes 128 --keep /tmp/stores
    .venv/bin/python scripts/bench_pipeline_memory.py --sizes 1024 --fit-samples 65536 --merge
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

from _common import ROOT, cpu_model, parser, run_self_json

FIGURES = ROOT / "docs" / "figures"


def _peak_mib() -> float:
    from relight.simulation import peak_rss_mib

    return peak_rss_mib()


def _reset_peak() -> bool:
    """Reset the process's peak RSS to its current RSS (Linux >= 4.0), after
    handing freed heap back (``relight.simulation.release_freed_memory``, as
    ``relight simulate`` does after building the grid), so the next phase's peak
    starts from what is live; False where that is not possible."""
    from relight.simulation import release_freed_memory

    release_freed_memory()
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _mark_grid(marks: dict, after=None) -> None:
    """Wrap ``stage.texel_samples`` (the texel grid, built first by simulate and by
    ``open_texel_capture``) so that its first call records its time and the peak so far
    into ``marks``, resets the peak, then calls ``after()``."""
    import stage

    build = stage.texel_samples

    def texel_samples(*a, **k):
        t = time.perf_counter()
        out = build(*a, **k)
        if "peak_surface_mib" not in marks:
            marks["grid_s"] = time.perf_counter() - t
            marks["peak_surface_mib"] = _peak_mib()
            marks["reset"] = _reset_peak()
            if after is not None:
                after()
        return out

    stage.texel_samples = texel_samples


def child_simulate(args) -> None:
    """One simulate: the CLI into args.store; prints JSON."""
    from relight.cli import main

    marks = {}
    _mark_grid(marks)
    t = time.perf_counter()
    rc = main(["simulate", "--resolution", str(args.res), "--out", args.store, "--block", str(args.block), "--quiet"])
    wall = time.perf_counter() - t
    assert rc == 0, rc
    settings = json.loads((Path(args.store) / "settings.json").read_text())["resolved"]
    rest = _peak_mib()
    marks["surface_s"] = marks.pop("grid_s")
    print(json.dumps({"wall_s": wall, "peak_mib": max(rest, marks["peak_surface_mib"]), "peak_rest_mib": rest,
                      **marks, "seen": settings["samples_seen"], "timings_s": settings["timings_s"],
                      "phase_peaks_mib": settings["peak_rss_mib"], "blocks": settings["blocks"],
                      "block_texels": settings["block_texels"], "store_chunks": settings["store_chunks"]}))


def child_fit(args) -> None:
    """One fit from args.store, read as ``relight fit`` reads it (``relight.io.open_texel_capture``: a
    ``SampleSubset`` of the store over the texels with a valid observation); prints JSON."""
    import numpy as np

    import relight
    from relight.io import SampleSubset, open_texel_capture

    marks = {}

    def surface_built():  # the mesh read and its grid built: the rest of open_texel_capture is the seen pass
        marks["surface_s"] = time.perf_counter() - t
        marks["t_seen"] = time.perf_counter()

    _mark_grid(marks, surface_built)
    t = time.perf_counter()
    capture, surface, _, _ = open_texel_capture(args.store)
    marks.pop("grid_s")
    seen_s = time.perf_counter() - marks.pop("t_seen")
    seen = capture.n_samples
    if args.fit_samples and args.fit_samples < seen:
        capture = SampleSubset(capture.source, capture.index[: args.fit_samples])
        surface = surface.subset(np.arange(args.fit_samples))
    stamps = []
    t0 = time.perf_counter()
    f = relight.fit(capture, surface, model="ggx", options=relight.fitting.FitOptions(
        rounds=3,  # the step budget docs/figures/pipeline_memory.md was measured with
        block=args.block, on_block=lambda s, e, _: stamps.append((e, time.perf_counter()))))
    fit_s = time.perf_counter() - t0
    assert np.all(np.isfinite(np.asarray(f.rho_d)))
    P = surface.num_samples
    first_n, first_t = stamps[0][0], stamps[0][1] - t0
    if len(stamps) > 1:
        rate = (P - first_n) / (stamps[-1][1] - stamps[0][1])
        compile_s = max(0.0, first_t - first_n / rate)
    else:
        rate, compile_s = None, None
    rest = _peak_mib()
    print(json.dumps({"wall_s": marks["surface_s"] + seen_s + fit_s, "seen_pass_s": seen_s, "fit_s": fit_s,
                      "peak_mib": max(rest, marks["peak_surface_mib"]), "peak_rest_mib": rest, **marks,
                      "fitted": int(P), "seen": int(seen), "first_block_s": first_t, "texels_per_s": rate,
                      "compile_s": compile_s, "failed_fraction": float(np.mean(np.asarray(f.failed)))}))


def _table(rows, base) -> str:
    head = ("| grid | seen texels | simulate peak (MiB) | x 128^2 | surface build | streaming | simulate wall (s) "
            "| fit peak (MiB) | x 128^2 | surface build | fit | texels fitted | fit texels/s | compile (s) "
            "| fit wall (s) |")
    lines = [head, "|" + "|".join("---" for _ in range(15)) + "|"]
    for r in rows:
        s, f = r["simulate"], r["fit"]
        bs, bf = base["simulate"]["peak_mib"], base["fit"]["peak_mib"]
        rate = "-" if f["texels_per_s"] is None else f"{f['texels_per_s']:.0f}"
        comp = "-" if f["compile_s"] is None else f"{f['compile_s']:.0f}"
        lines.append(f"| {r['res']}^2 | {s['seen']} | {s['peak_mib']:.0f} | {s['peak_mib'] / bs:.2f} | "
                     f"{s['peak_surface_mib']:.0f} | {s['peak_rest_mib']:.0f} | {s['wall_s']:.0f} | "
                     f"{f['peak_mib']:.0f} | {f['peak_mib'] / bf:.2f} | {f['peak_surface_mib']:.0f} | "
                     f"{f['peak_rest_mib']:.0f} | {f['fitted']} | {rate} | {comp} | {f['wall_s']:.0f} |")
    return "\n".join(lines)


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument("--sizes", type=int, nargs="+", default=[128, 512, 1024])
    ap.add_argument("--sim-block", type=int, default=1 << 14, help="relight simulate --block (texels)")
    ap.add_argument("--fit-block", type=int, default=4096, help="relight.fit block (samples)")
    ap.add_argument("--fit-samples", type=int, default=0,
                    help="fit only the first K seen texels of grids >= --bound-from (0: all)")
    ap.add_argument("--bound-from", type=int, default=1024, help="smallest grid --fit-samples applies to")
    ap.add_argument("--keep", default=None, help="folder to keep the stores in (default: a temporary one)")
    ap.add_argument("--out", default=str(FIGURES / "pipeline_memory"), help="output stem (.md and .json)")
    ap.add_argument("--merge", action="store_true", help="merge with the rows already in OUT.json")
    ap.add_argument("--stages", nargs="+", choices=("simulate", "fit"), default=["simulate", "fit"],
                    help="what to measure (fit needs the stores: --keep FOLDER from an earlier simulate)")
    ap.add_argument("--child", choices=("simulate", "fit"))
    ap.add_argument("--res", type=int)
    ap.add_argument("--store")
    ap.add_argument("--block", type=int)
    args = ap.parse_args()
    if args.child == "simulate":
        return child_simulate(args)
    if args.child == "fit":
        return child_fit(args)
    out = Path(args.out)
    rows = {}
    if args.merge and out.with_suffix(".json").is_file():
        rows = {r["res"]: r for r in json.loads(out.with_suffix(".json").read_text())["rows"]}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(args.keep or tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for res in args.sizes:
            store = str(folder / f"head{res}.zarr")
            row = rows.setdefault(res, {"res": res})
            if "simulate" in args.stages:
                row["simulate"] = run_self_json(__file__, ["--child", "simulate", "--res", str(res), "--store", store,
                                                           "--block", str(args.sim_block)])
                print(f"{res}^2 simulate: {json.dumps(row['simulate'])}", flush=True)
            if "fit" in args.stages:
                k = args.fit_samples if res >= args.bound_from else 0
                row["fit"] = run_self_json(__file__, ["--child", "fit", "--store", store, "--block",
                                                      str(args.fit_block), *(["--fit-samples", str(k)] if k else [])])
                row["fit_samples"] = k or None
                print(f"{res}^2 fit: {json.dumps(row['fit'])}", flush=True)
            _save(out, rows, args)
            if not args.keep:
                import shutil

                shutil.rmtree(store, ignore_errors=True)
    ordered = [rows[k] for k in sorted(rows)]
    if all("simulate" in r and "fit" in r for r in ordered):
        print(_table(ordered, rows.get(128, ordered[0])))


def _save(out: Path, rows: dict, args) -> None:
    """OUT.json: every row measured so far (written after each, so a long run keeps what it has)."""
    doc = {"command": "python scripts/bench_pipeline_memory.py " + " ".join(sys.argv[1:]),
           "machine": f"{cpu_model()} (shared with other jobs), " + platform.platform(),
           "date": datetime.date.today().isoformat(), "sim_block": args.sim_block, "fit_block": args.fit_block,
           "cpu_count": os.cpu_count(), "rows": [rows[k] for k in sorted(rows)]}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(doc, indent=1) + "\n")


if __name__ == "__main__":
    sys.exit(main())

"""Cold against warm persistent compilation cache for ``relight fit`` and ``relight simulate``.

Each measurement is one fresh process running ``relight <command>`` (``relight.cli.main``) with
``--cache-dir`` set: "cold" starts from an empty cache folder, "warm" reruns the same command on the
folder the cold run filled. The child counts, through ``jax.monitoring``, the XLA programs compiled
(backend compiles that missed the cache), those loaded from it (hits), the seconds in backend
compilation or cache loading (``/jax/core/compile/backend_compile_duration``), and the seconds tracing
and lowering (``jaxpr_trace_duration`` + ``jaxpr_to_mlir_module_duration``: the persistent cache does
not save those); the parent times the whole process (imports included). A second texel count, fitted
on the cache the first one filled, shows which programs a new capture size still compiles.

    .venv/bin/python scripts/bench_compile.py                          # writes docs/figures/compile_cache.md
    .venv/bin/python scripts/bench_compile.py --res 24 40 --out /tmp/compile_cache.md
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import ROOT, cpu_model, parser

_CHILD = """
import json, sys, time
import jax.monitoring as m
counts, secs = {}, {}
def on_event(name, **kw):
    counts[name] = counts.get(name, 0) + 1
def on_duration(name, s, **kw):
    counts[name] = counts.get(name, 0) + 1
    secs[name] = secs.get(name, 0.0) + s
m.register_event_listener(on_event)
m.register_event_duration_secs_listener(on_duration)
from relight.cli import main
t = time.perf_counter()
assert main(json.loads(sys.argv[1])) == 0
wall = time.perf_counter() - t
c = "/jax/compilation_cache/"
k = "/jax/core/compile/"
print(json.dumps({"command_s": wall, "hits": counts.get(c + "cache_hits", 0),
                  "misses": counts.get(c + "cache_misses", 0),
                  "programs": counts.get(k + "backend_compile_duration", 0),
                  "backend_s": secs.get(k + "backend_compile_duration", 0.0),
                  "trace_lower_s": secs.get(k + "jaxpr_trace_duration", 0.0)
                  + secs.get(k + "jaxpr_to_mlir_module_duration", 0.0)}))
"""


def _child(argv: list[str]) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("RELIGHT_CACHE_DIR", "XLA_FLAGS")}
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    t = time.perf_counter()
    run = subprocess.run([sys.executable, "-c", _CHILD, json.dumps(argv)], capture_output=True, text=True, env=env,
                         cwd=ROOT, check=False)
    if run.returncode:
        raise SystemExit(f"child failed (relight {' '.join(argv)}):\n{run.stderr[-3000:]}")
    out = json.loads(run.stdout.strip().splitlines()[-1])
    out["process_s"] = time.perf_counter() - t
    return out


def _simulate_argv(res: int, out: Path) -> list[str]:
    return ["simulate", "--rig", "dome:42", "--resolution", str(res), "--image-size", "32", "--out", str(out),
            "--quiet"]


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument("--res", type=int, nargs=2, default=(24, 40), help="two texel resolutions (default 24 40)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "figures" / "compile_cache.md"))
    args = ap.parse_args()
    ra, rb = args.res
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        caps = {}
        for r in (ra, rb):  # the inputs, made without a cache so the fits' cold runs start cold
            caps[r] = tmp / f"cap{r}"
            _child(["--cache-dir", "off", *_simulate_argv(r, caps[r])])
        from relight.io import open_texel_capture

        texels = {r: open_texel_capture(caps[r]).surface.num_samples for r in (ra, rb)}

        def fit(r, model, cache, tag):
            return _child(["--cache-dir", str(cache), "fit", str(caps[r]), "--out", str(tmp / f"m_{tag}"), "--model",
                           model, "--quiet"])

        for model in ("ggx", "auto"):
            cache = tmp / f"cache_{model}"
            off = _child(["--cache-dir", "off", "fit", str(caps[ra]), "--out", str(tmp / "m_off"), "--model", model,
                          "--quiet"])
            cold = fit(ra, model, cache, f"{model}_cold")
            warm = fit(ra, model, cache, f"{model}_warm")
            other = fit(rb, model, cache, f"{model}_other")  # a second size on the first size's cache
            rows.append((f"fit --model {model}", texels[ra], texels[rb], off, cold, warm, other))
        cache = tmp / "cache_sim"
        off = _child(["--cache-dir", "off", *_simulate_argv(ra, tmp / "s_off")])
        cold = _child(["--cache-dir", str(cache), *_simulate_argv(ra, tmp / "s_cold")])
        warm = _child(["--cache-dir", str(cache), *_simulate_argv(ra, tmp / "s_warm")])
        other = _child(["--cache-dir", str(cache), *_simulate_argv(rb, tmp / "s_other")])
        rows.append(("simulate", f"{ra}x{ra}", f"{rb}x{rb}", off, cold, warm, other))
        entries = sum(1 for p in tmp.glob("cache_*/*") if p.is_file())
        size = sum(p.stat().st_size for p in tmp.glob("cache_*/*") if p.is_file())
    print(json.dumps(rows, indent=1, default=str))
    Path(args.out).write_text(_markdown(rows, args, entries, size))
    print(f"wrote {args.out}")


def _markdown(rows, args, entries: int, size: int) -> str:
    cpu = cpu_model()
    date = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    lines = ["# Persistent compilation cache: cold against warm", "",
             f"`{' '.join(['.venv/bin/python', 'scripts/bench_compile.py', '--res', *map(str, args.res)])}`, "
             f"{date}, {cpu} (2 cores, shared with other jobs: wall times vary run to run by tens of percent; "
             "the program counts do not), Python "
             f"{platform.python_version()}. Captures: `relight simulate --rig dome:42 --resolution R "
             "--image-size 32` (bundled head, one camera). Each column is one fresh process; *cold* starts "
             "from an empty `--cache-dir`, *warm* reruns the same command on it, *other size* runs the command "
             "on the second capture with the cache the first one filled; *off* is `--cache-dir off`.", "",
             "| command | texels (first / other) | | off | cold | warm | other size |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for name, a, b, off, cold, warm, other in rows:
        def cell(r, key, fmt):
            return fmt.format(r[key])
        lines += [
            f"| `{name}` | {a} / {b} | process wall (s) | {cell(off, 'process_s', '{:.1f}')} | "
            f"{cell(cold, 'process_s', '{:.1f}')} | {cell(warm, 'process_s', '{:.1f}')} | "
            f"{cell(other, 'process_s', '{:.1f}')} |",
            f"| | | compile or load (s) | {off['backend_s']:.1f} | {cold['backend_s']:.1f} | {warm['backend_s']:.2f} | "
            f"{other['backend_s']:.2f} |",
            f"| | | trace + lower (s) | {off['trace_lower_s']:.1f} | {cold['trace_lower_s']:.1f} | "
            f"{warm['trace_lower_s']:.1f} | {other['trace_lower_s']:.1f} |",
            f"| | | programs compiled / loaded | {off['programs']} / 0 | {cold['misses']} / {cold['hits']} | "
            f"{warm['misses']} / {warm['hits']} | {other['misses']} / {other['hits']} |"]
    lines += ["", "Ratios (cold / warm): " + "; ".join(
        f"`{name}` process {cold['process_s'] / warm['process_s']:.1f}x, compile "
        f"{cold['backend_s'] / max(warm['backend_s'], 1e-9):.0f}x" for name, _, _, _, cold, warm, _ in rows) + ".",
        "", f"The caches held {entries} entries, {size / 2**20:.1f} MiB in all. A hit in the first process is a "
        "program compiled twice there (the same computation under two names). What a warm run still spends "
        "is Python, tracing and lowering (not cached: JAX keys its cache on the lowered program), reading the "
        "capture and writing the maps. The *other size* column counts the programs whose shapes follow the "
        "capture: the solver's do not (their sample count is the chunk, their observation count a bucket: "
        "`relight.fitting._observations._obs_bucket`), the per-texel map assembly and the report's do.", ""]
    return "\n".join(lines)


if __name__ == "__main__":
    main()

"""A light-stage delivery at realistic sizes, end to end through the command line: photographs -> texel store ->
fit -> render, with the wall time and peak resident memory of every stage, and the decode rate of the same
photographs with a plain decoder loop (pypng for PNG, OpenEXR for EXR) as the baseline measured in the same run.

Per size S (image side in pixels; the texel grid is S x S too): ``relight simulate --space image`` writes the
delivery (the bundled head, the full Light Stage X, 3 cameras over 60 degrees, one photograph per camera and
light through the sensor: Poisson + read noise at 2000 photo-electrons per unit radiance; ``--format png``, the
default: 16-bit PNGs of the counts, as a camera delivers them, clipped counts invalid; ``exr``: float32 EXRs of the
radiance), then, each its own process:

* ``decode``: the baseline, every photograph of the delivery read in a loop with a plain decoder (``png.Reader``
  for PNG, ``OpenEXR.File`` for EXR; no resampling, no writing): what reading the delivery costs at the
  decoder's speed; for PNG also the floor, the files' IDAT data only inflated (``zlib.decompress``), since
  relight's own PNG reader (zlib + NumPy) is faster than pypng;
* ``convert``: ``relight convert PHOTOS S.zarr --mesh head --resolution S`` (``relight.io.photos_to_texel_store``:
  a light chunk of photographs at a time into the texel store);
* ``fit``: ``relight fit S.zarr --model ggx`` (block by block from the store; compile included);
* ``render``: ``relight render FIT --image-size S`` (the fitted maps under the bundled environment map).

Throughput: pixel-observations (cameras x lights x S^2) per second in for decode and convert, fitted texels per
second for the fit. The peak of each process is its own (``os.wait4``'s ``ru_maxrss``). The simulation writes
each light chunk of a camera as it is made (``stage.iter_images`` into ``relight.io.PhotoCaptureWriter``), so
its memory too is a chunk, not the delivery (3 x 346 x S^2 x 3 float32: 13 GiB at 1024).

    python scripts/bench_delivery.py                      # 256 and 512
    python scripts/bench_delivery.py --sizes 256,512,1024 --keep /tmp/delivery
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import FIG, ROOT, machine, parser

STAGES = ("simulate", "decode", "convert", "fit", "render")
# The 1-minute load average at the start and end of every stage (the machine may be shared; said in the table).
_LOAD: list[float] = []
_DECODE = {"exr": """
import sys, time, json, OpenEXR
files = sys.argv[1:]
t = time.perf_counter(); n = 0
for f in files:
    with OpenEXR.File(f) as e:
        for c in e.channels().values():
            n += c.pixels.size
print(json.dumps({"seconds": time.perf_counter() - t, "values": n}))
""", "png": """
import sys, time, json, zlib, png
files = sys.argv[1:]
t = time.perf_counter(); n = 0
for f in files:
    w, h, rows, info = png.Reader(bytes=open(f, "rb").read()).read_flat()
    n += len(rows)
seconds = time.perf_counter() - t
t = time.perf_counter()
for f in files:  # the floor: the IDAT chunks inflated, nothing else
    data, i, idat = open(f, "rb").read(), 8, []
    while i < len(data):
        k = int.from_bytes(data[i:i + 4], "big")
        if data[i + 4:i + 8] == b"IDAT":
            idat.append(data[i + 8:i + 8 + k])
        i += 12 + k
    zlib.decompress(b"".join(idat))
print(json.dumps({"seconds": seconds, "values": n, "inflate_seconds": time.perf_counter() - t}))
"""}


def _run(cmd: list[str], log: Path) -> tuple[float, float, str]:
    """Run ``cmd`` (cwd: the repository) with stdout and stderr into ``log``; (wall seconds, peak RSS MiB, its
    stdout's last line). A failing command stops the benchmark with the tail of its log."""
    t = time.perf_counter()
    _LOAD.append(os.getloadavg()[0])
    with open(log, "w") as out:
        p = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, cwd=ROOT)
        _, status, usage = os.wait4(p.pid, 0)
    seconds = time.perf_counter() - t
    _LOAD.append(os.getloadavg()[0])
    p.returncode = os.waitstatus_to_exitcode(status)
    text = log.read_text()
    if p.returncode:
        raise SystemExit(f"failed ({' '.join(map(str, cmd))}):\n{text[-3000:]}")
    last = text.strip().splitlines()[-1] if text.strip() else ""
    return seconds, usage.ru_maxrss / 1024.0, last


def _cameras(path: Path, size: int) -> None:
    """Three cameras of size x size pixels over 60 degrees around the front of the bundled head, framing it."""
    import numpy as np

    import stage

    v = np.asarray(stage.load_head().vertices, np.float64)
    c = tuple(0.5 * (v.min(0) + v.max(0)))
    cams = stage.camera_ring(3, 1300.0, target=c, fov_deg=20.0, width=size, height=size, start_deg=-30, arc_deg=60)
    stage.save_cameras(path, cams, names=["left", "front", "right"])


def bench_size(size: int, work: Path, lights: int, fmt: str, photos_dir: Path | None = None,
               decode_sample: int = 0) -> dict:
    """Every stage at one size, in ``work``; the row of the table. ``photos_dir``: a delivery of this size that
    an earlier run simulated (not simulated again: its simulation time is the one its settings.json records,
    its peak is not known); ``decode_sample`` > 0: the baseline decodes that many of the files, evenly spaced,
    and its time is scaled to all of them."""
    relight = [sys.executable, "-c", "import sys; from relight.cli import main; sys.exit(main(sys.argv[1:]))"]
    cams = work / "cameras.json"
    _cameras(cams, size)
    photos, store, fit, render = (work / n for n in ("photos", f"{size}.zarr", "fit", "render"))
    rig = ["--rig", "lsx" if lights == 346 else f"dome:{lights}"]
    row = {"size": size, "texels": size * size}
    _LOAD.clear()
    stages = {}
    if photos_dir is None:
        stages["simulate"] = _run([*relight, "simulate", "--space", "image", *rig, "--camera", str(cams),
                                   "--noise", "2000", "--read-noise", "2", "--format", fmt, "--out", str(photos),
                                   "--no-index", "-q"], work / "simulate.log")
    else:
        photos = photos_dir
        took = json.loads((photos / "settings.json").read_text())["resolved"]["timings_s"]
        stages["simulate"] = (sum(took.values()), float("nan"), "")
    files = sorted(str(p) for p in photos.rglob(f"l*.{fmt}"))
    step = max(1, -(-len(files) // decode_sample)) if decode_sample > 0 else 1
    t, peak, last = _run([sys.executable, "-c", _DECODE[fmt], *files[::step]], work / "decode.log")
    scale = len(files) / len(files[::step])
    doc = json.loads(last)
    last = json.dumps({k: v * scale if k != "values" else int(v * scale) for k, v in doc.items()})
    stages["decode"] = (t * scale, peak, last)
    stages["convert"] = _run([*relight, "convert", str(photos), str(store), "--mesh", "head", "--resolution",
                              str(size), "--no-index", "-q"], work / "convert.log")
    stages["fit"] = _run([*relight, "fit", str(store), "--model", "ggx", "--out", str(fit), "--no-index", "-q"],
                         work / "fit.log")
    stages["render"] = _run([*relight, "render", str(fit), "--image-size", str(size), "--out", str(render),
                             "--no-index", "-q"], work / "render.log")
    report = json.loads((fit / "report.json").read_text())
    obs = 3 * lights * size * size
    decoded = json.loads(stages["decode"][2])
    row.update({f"{k}_s": round(v[0], 1) for k, v in stages.items()})
    row.update({f"{k}_peak_mib": round(v[1]) if math.isfinite(v[1]) else None for k, v in stages.items()})
    clipped = json.loads((photos / "settings.json").read_text())["resolved"]["clipped_fraction"]
    row.update(decode_files_timed=len(files[::step]), format=fmt, observations=obs, photo_files=len(files),
               decode_values=int(decoded["values"]),
               clipped_fraction=clipped, inflate_s=round(decoded.get("inflate_seconds", float("nan")), 1),
               seen_texels=int(report["seen_samples"]),
               decode_obs_per_s=obs / stages["decode"][0], convert_obs_per_s=obs / stages["convert"][0],
               fit_texels_per_s=report["seen_samples"] / stages["fit"][0],
               load_average=round(sum(_LOAD) / len(_LOAD), 2), cores=os.cpu_count())
    return row


def _table(rows: list[dict], cmd: str) -> str:
    lines = [f"Machine: {machine()}. Command: `{cmd}`.", "",
             "Wall time (s) and peak resident memory (MiB) of each stage, each its own process. Simulate: "
             f"`relight simulate --space image --format {rows[0]['format']}` (the delivery, written a light chunk "
             "at a time); decode: the photographs read by a plain decoder loop (the baseline); convert: `relight "
             "convert PHOTOS S.zarr --mesh head` (photographs to the texel store, a light chunk at a time); fit: "
             "`relight fit S.zarr --model ggx` over the texels a camera sees (compile included); render: "
             "`relight render FIT`. Clipped: the delivery's values at full scale, over the seen pixels. Load "
             "average: the machine's 1-minute load over the size's stages (above the core count, the wall times "
             "are stretched by other work; the peaks are not).", "",
             "| size (px = texels) | simulate s | decode s | convert s (x decode) | fit s | render s | "
             "peak MiB: simulate / convert / fit / render | convert Mobs/s (decode) | fit texels/s | seen texels | "
             "clipped | load average |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['size']}^2 | {r['simulate_s']} | {r['decode_s']}{_inflate(r)} | {r['convert_s']} "
            f"({r['convert_s'] / max(r['decode_s'], 1e-9):.1f}x) | {r['fit_s']} | {r['render_s']} | "
            f"{' / '.join(str(r[f'{k}_peak_mib'] or '-') for k in STAGES if k != 'decode')} | "
            f"{r['convert_obs_per_s'] / 1e6:.1f} ({r['decode_obs_per_s'] / 1e6:.1f}) | "
            f"{r['fit_texels_per_s']:.0f} | {r['seen_texels']} | {100 * r['clipped_fraction']:.3f}% | "
            f"{r.get('load_average', '-')} on {r.get('cores', '-')} cores |")
    if len(rows) > 1:
        a, b = rows[0], rows[-1]
        ratios = ", ".join(f"{k} {b[f'{k}_peak_mib'] / a[f'{k}_peak_mib']:.2f}x" for k in STAGES
                           if k != "decode" and a[f"{k}_peak_mib"] and b[f"{k}_peak_mib"])
        lines += ["", f"Peak memory at {b['size']}^2 over {a['size']}^2: {ratios} (the capture grew "
                      f"{b['observations'] / a['observations']:.0f}x)."]
    return "\n".join(lines) + "\n"


def _inflate(row: dict) -> str:
    """" (inflate S)" where the row has the PNG floor's seconds."""
    v = row.get("inflate_s")
    return f" (inflate {v})" if isinstance(v, (int, float)) and math.isfinite(v) else ""


def _write(path: Path, text: str) -> None:
    """``text`` into ``path`` whole or not at all (a sibling temporary file, then one rename)."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def main(argv=None) -> None:
    ap = parser(__doc__)
    ap.add_argument("--sizes", default="256,512", help="image sides (= texel grid sides), comma-separated")
    ap.add_argument("--lights", type=int, default=346, help="346: the Light Stage X; else a dome:N rig")
    ap.add_argument("--format", default="png", choices=("png", "exr"), dest="fmt",
                    help="the photographs: 16-bit PNG counts (default) or float32 EXR radiance")
    ap.add_argument("--keep", type=Path, default=None, help="keep each size's files under this folder")
    ap.add_argument("--out", type=Path, default=FIG, help="where delivery.md / delivery.json go")
    ap.add_argument("--photos", type=Path, default=None,
                    help="with one size: an existing delivery of that size to use instead of simulating one")
    ap.add_argument("--decode-sample", type=int, default=0, metavar="N",
                    help="time the decode baseline on N of the files, evenly spaced, scaled to all (0: all)")
    ap.add_argument("--append", action="store_true",
                    help="keep the rows of other sizes already in OUT/delivery.json (the same rig and format): "
                         "sizes run in separate invocations, one table")
    a = ap.parse_args(argv)
    sizes = [int(s) for s in a.sizes.split(",")]
    cmd = "python scripts/bench_delivery.py" + ("" if a.sizes == "256,512" else f" --sizes {a.sizes}") + (
        "" if a.lights == 346 else f" --lights {a.lights}") + ("" if a.fmt == "png" else f" --format {a.fmt}") + (
        "" if a.photos is None else f" --photos {a.photos}") + (
        f" --decode-sample {a.decode_sample}" if a.decode_sample else "")
    rows, cmds = [], [cmd]
    old = a.out / "delivery.json"
    if a.append and old.is_file():
        doc = json.loads(old.read_text())
        rows = [r for r in doc["rows"] if r["size"] not in sizes and r.get("format") == a.fmt
                and r["observations"] == 3 * a.lights * r["size"] ** 2]
        cmds = [c for c in doc.get("commands", [doc.get("command")]) if c and c != cmd] + cmds
    a.out.mkdir(parents=True, exist_ok=True)
    for size in sizes:
        work = Path(tempfile.mkdtemp(prefix=f"delivery{size}_")) if a.keep is None else a.keep / str(size)
        work.mkdir(parents=True, exist_ok=True)
        try:
            rows.append(bench_size(size, work, a.lights, a.fmt, a.photos, a.decode_sample))
            print(json.dumps(rows[-1]), flush=True)
        finally:
            if a.keep is None:
                shutil.rmtree(work, ignore_errors=True)
        rows.sort(key=lambda r: r["size"])
        # Written after every size: a long run's finished sizes are kept if a later one is stopped.
        _write(old, json.dumps({"machine": machine(), "commands": cmds, "rows": rows}, indent=1))
        _write(a.out / "delivery.md", _table(rows, "`; `".join(cmds)))
    print(_table(rows, "`; `".join(cmds)))

if __name__ == "__main__":
    main()

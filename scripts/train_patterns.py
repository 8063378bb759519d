"""Train learned lighting patterns (Kang et al. 2018) for the Light Stage X, one
autoencoder per pattern count.

    .venv/bin/python scripts/train_patterns.py                       # K = 4, 8, 16, 32, 64 -> build/patterns/
    .venv/bin/python scripts/train_patterns.py --patterns 32 --steps 500 --out /tmp/p
    .venv/bin/python scripts/train_patterns.py --data                # also copy the pattern files to relight/data/

Setting (docs/patterns.md): the Light Stage X (346 near-field lights,
``stage.light_stage_x()``: irradiance 1 at the centre per light), one camera
1 m in front on +z, samples in a 100 mm ball about the centre with normals
within 75 degrees of the view direction, Lambert + GGX materials over
``relight.patterns.ParameterRanges()`` (rho_d 0.02-0.95, F0 0-0.12 with 10%
Lambert-only, alpha 0.05-0.8 log-uniform), the sensor ``SENSOR`` (per-frame
exposure 2000 photo-electrons per unit radiance, shot noise, 5 e- read noise).
Every step draws a fresh batch (``relight.patterns.train``; seed per K).

Writes, per K, ``<out>/lsx_K<K>.patterns.json`` (``stage.save_patterns``: the
file the rig plays), ``.eqx`` (decoders and patterns, equinox leaves), ``.json``
(the network's shape and the training metadata) and ``<out>/train_log.json``
(loss history, wall time, machine).
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import jax
import numpy as np
from _common import PATTERN_CAMERA_EYE as CAMERA_EYE
from _common import PATTERN_SENSOR as SENSOR
from _common import ROOT, machine, parser

import relight.patterns as rp
import stage


def main(argv=None) -> int:
    ap = parser(__doc__)
    ap.add_argument("--patterns", default="4,8,16,32,64", help="pattern counts K, comma separated")
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--batch", type=int, default=256)
    ap.add_argument("--lr", type=float, default=3e-3)
    ap.add_argument("--width", type=int, default=192)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-grid", dest="grid", action="store_false",
                    help="decoder without the closed-form specular features (relight.patterns.ALPHA_GRID)")
    ap.add_argument("--out", type=Path, default=ROOT / "build" / "patterns")
    ap.add_argument("--data", action="store_true", help="copy the .patterns.json files to relight/data/")
    args = ap.parse_args(argv)
    ks = [int(k) for k in args.patterns.split(",")]
    args.out.mkdir(parents=True, exist_ok=True)
    rig = stage.light_stage_x()
    sensor = stage.Sensor(**SENSOR)
    log_path = args.out / "train_log.json"
    old = json.loads(log_path.read_text()) if log_path.is_file() else {}
    log = {"machine": machine(), "sensor": SENSOR, "camera_eye_mm": CAMERA_EYE, "runs": old.get("runs", [])}
    for k in ks:
        cfg = rp.TrainConfig(steps=args.steps, batch=args.batch, lr=args.lr, seed=args.seed + k, width=args.width,
                             grid=rp.ALPHA_GRID if args.grid else ())
        t0 = time.time()

        def progress(phase, done, total, t0=t0):
            if done:
                print(f"  {phase}: {done}/{total} steps, {time.time() - t0:.0f} s", flush=True)

        model, hist = rp.train(rig, CAMERA_EYE, k, sensor, cfg, progress=progress, log_every=max(args.steps // 10, 1))
        wall = time.time() - t0
        meta = {"rig": "light_stage_x", "num_patterns": k, "steps": args.steps, "batch": args.batch, "lr": args.lr,
                "seed": cfg.seed, "width": args.width, "grid": list(cfg.grid), "sensor": SENSOR,
                "camera_eye_mm": CAMERA_EYE,
                "paper": "Kang et al. 2018, Efficient Reflectance Capture Using an Autoencoder"}
        rp.save_model(args.out / f"lsx_K{k}", model, rig, metadata=meta)
        if args.data:
            shutil.copyfile(args.out / f"lsx_K{k}.patterns.json", ROOT / "relight" / "data" / f"patterns_lsx_K{k}.json")
        W = np.asarray(model.patterns)
        print(f"K={k}: {wall:.0f} s, final loss {hist[-1]['loss']:.4f} (rho_d {hist[-1]['rho_d']:.4f}, "
              f"alpha {hist[-1]['alpha']:.4f}), weights {W.min():.3f}..{W.max():.3f} mean {W.mean():.3f}",
              flush=True)
        log["runs"] = [r for r in log["runs"] if r["K"] != k] + [{"K": k, "wall_s": wall, "history": hist,
                                                                  "jax": jax.__version__}]
        log_path.write_text(json.dumps(log, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

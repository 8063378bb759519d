"""The fitter's step budget on real data: for each DiLiGenT object, rung and number of rounds (20 solver
steps each), the fraction of pixels flagged ``failed`` (all of them: the solver's step budget ran out),
the mean normal error against Normal_gt.mat over every mask pixel, and the fit's time (compiled, warm).
A budget is large enough when its flags no longer fall with more rounds while the error does not move:
then ``failed`` marks samples the solver cannot fit, not samples it had no time for.

    python scripts/eval_rounds.py [--objects ballPNG,catPNG] [--rounds 3,6,8,12] [--out docs/figures]

Writes rounds.md and rounds.json into ``--out``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
from _common import FIG, diligent_objects, machine, parser


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("--objects", default="ballPNG,catPNG")
    ap.add_argument("--models", default="blinn_phong,ggx")
    ap.add_argument("--rounds", default="3,6,8,12")
    ap.add_argument("--out", type=Path, default=FIG)
    a = ap.parse_args(argv)

    import relight
    from relight.fitting import FitOptions, angular_error_deg
    from relight.io import diligent_capture

    rows = []
    for obj, d in diligent_objects(a.objects):
        cap, surface = diligent_capture(d)
        gt = d.normals_gt[d.mask]
        for model in a.models.split(","):
            relight.fit(cap, surface, model=model, normals=True, options=FitOptions(rounds=1))  # compile
            for r in (int(x) for x in a.rounds.split(",")):
                t0 = time.perf_counter()
                f = relight.fit(cap, surface, model=model, normals=True, options=FitOptions(rounds=r))
                seconds = time.perf_counter() - t0
                err = angular_error_deg(np.asarray(f.normal, np.float64), gt)
                row = dict(object=obj, model=model, rounds=r, pixels=int(d.mask.sum()),
                           failed=float(np.mean(np.asarray(f.failed))), normal_mean_deg=float(err.mean()),
                           seconds=round(seconds, 1))
                rows.append(row)
                print(f"{obj} {model:11s} rounds {r:2d}: failed {row['failed']:.3f}, mean normal error "
                      f"{row['normal_mean_deg']:.3f} deg, {seconds:.1f} s", flush=True)
    md = ["| object | rung | rounds (x 20 steps) | failed | mean normal error (deg) | fit time (s) |",
          "| --- | --- | --- | --- | --- | --- |"]
    md += [f"| {r['object']} | {r['model']} | {r['rounds']} | {100 * r['failed']:.1f}% | "
           f"{r['normal_mean_deg']:.3f} | {r['seconds']} |" for r in rows]
    md += ["", f"Over every mask pixel of each object (fraction and mean); fit time warm (compiled). {machine()}"]
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "rounds.json").write_text(json.dumps(dict(machine=machine(), rows=rows), indent=1))
    (a.out / "rounds.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()

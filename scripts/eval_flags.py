"""What the fit's per-sample flags mean on real data: for each DiLiGenT object and rung, the fraction of pixels
each flag marks (``failed``, ``ambiguous``, ``unresolved``, ``collapsed``) and the mean normal error against
Normal_gt.mat of the flagged pixels next to the unflagged ones. DiLiGenT has no reflectance truth, so the normal
is the one measured error; a flag about the lobe (``collapsed``, ``unresolved``) says its F0 and roughness are
not measurements, which a normal error need not show.

    python scripts/eval_flags.py [--objects ballPNG,catPNG] [--models blinn_phong,ggx,auto] [--subsample 1]

Writes flags.md and flags.json into ``--out``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from _common import FIG, diligent_objects, machine, parser

FLAGS = ("failed", "ambiguous", "unresolved", "collapsed")


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("--objects", default="ballPNG,catPNG")
    ap.add_argument("--models", default="blinn_phong,ggx,auto")
    ap.add_argument("--subsample", type=int, default=1, help="fit every k-th pixel in x and y")
    ap.add_argument("--out", type=Path, default=FIG)
    a = ap.parse_args(argv)

    from relight.fitting import angular_error_deg, fit_diligent

    rows = []
    for obj, d in diligent_objects(a.objects):
        keep = np.zeros_like(d.mask)
        keep[:: a.subsample, :: a.subsample] = True
        gt = d.normals_gt[d.mask & keep].astype(np.float64)
        for model in a.models.split(","):
            f, _, _ = fit_diligent(d, name=obj, subsample=a.subsample, model=model)
            err = angular_error_deg(np.asarray(f.normal, np.float64), gt)
            row = dict(object=obj, model=model, pixels=int(err.size), normal_mean_deg=float(err.mean()))
            for name in FLAGS:
                flag = np.asarray(getattr(f, name), bool)
                row[name] = dict(fraction=float(flag.mean()),
                                 flagged_mean_deg=float(err[flag].mean()) if flag.any() else None,
                                 unflagged_mean_deg=float(err[~flag].mean()) if (~flag).any() else None)
            rows.append(row)
            print(f"{obj} {model:11s}: " + ", ".join(f"{n} {100 * row[n]['fraction']:.1f}%" for n in FLAGS),
                  flush=True)

    def cell(v):
        if v["fraction"] == 0:
            return "0%"
        g = lambda x: "-" if x is None else f"{x:.2f}"  # noqa: E731
        return f"{100 * v['fraction']:.1f}% ({g(v['flagged_mean_deg'])} / {g(v['unflagged_mean_deg'])})"

    md = [f"Machine: {machine()}. Command: `python scripts/eval_flags.py"
          f"{'' if a.subsample == 1 else f' --subsample {a.subsample}'}`.", "",
          "Per flag: the fraction of the object's mask pixels it marks (every pixel fitted once, with the normal)"
          " and, in brackets, the mean normal error in degrees of the flagged / the unflagged pixels.", "",
          "| object | rung | pixels | mean normal error (deg) | " + " | ".join(FLAGS) + " |",
          "| --- | --- | --- | --- | " + " | ".join("---" for _ in FLAGS) + " |"]
    md += [f"| {r['object']} | {r['model']} | {r['pixels']} | {r['normal_mean_deg']:.2f} | "
           + " | ".join(cell(r[n]) for n in FLAGS) + " |" for r in rows]
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "flags.md").write_text("\n".join(md) + "\n")
    (a.out / "flags.json").write_text(json.dumps(dict(machine=machine(), subsample=a.subsample, rows=rows),
                                                 indent=1) + "\n")
    print(f"wrote {a.out / 'flags.md'} and flags.json")


if __name__ == "__main__":
    main()

"""The outside-data suite: relight.fit on real photographs nobody here made, scored by held-out-light
prediction against per-pixel Lambertian least squares (relight.evaluation).

    python scripts/eval_outside.py [--sections yaleb,diligent] [--out docs/figures]

Sections (each a dataset under ../shared/data; a missing one is skipped with a line saying so):
- ``yaleb``: the 11 Extended Yale B subjects (real faces, 64 strobes, 8-bit; relight.io.read_yaleb). Every
  fourth light (16 of 64) is held out. The baseline fits the training observations that are neither dark
  (< 1% of full scale) nor saturated; the score is the relative RMS over the held-out in-face observations
  that are neither dark nor saturated. Pixels: every ``--yaleb-stride``-th row and column of the face mask.
- ``diligent``: DiLiGenT ball and cat (16-bit, 96 calibrated lights, ground-truth normals). Every sixth light
  (16 of 96) is held out (scripts/eval_diligent.py's protocol: the baseline fits every training light, the
  score is over in-mask unsaturated observations of lights in front of the object). The normal error is the
  training fit's, against Normal_gt.mat, over every mask pixel.

Each (model, loss) pair is a ``relight.fit(..., normals=True)`` on the training lights with the library's
defaults otherwise. Writes outside.json and outside.md into ``--out``.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np
from _common import ROOT, machine, parser

DATA = ROOT.parent / "shared" / "data"


def _score(data, train, held, fits, *, dark, saturation, front_only, baseline_valid):
    """Baseline and fitted held-out relative RMS for one capture; one row dict per (model, loss)."""
    import relight
    import relight.evaluation as ev
    from relight.fitting import angular_error_deg
    from relight.io import diligent_capture

    vtrain = ev.observation_validity(data, train, dark=dark, saturation=saturation) if baseline_valid else None
    normal, albedo = ev.lambert_least_squares(data, train, vtrain)
    observed = data.images[held][:, data.mask, :]
    valid = ev.observation_validity(data, held, dark=dark, saturation=saturation)
    if front_only:
        valid &= (data.light_directions[held, 2] > 0)[:, None]
    base = ev.relative_rms(ev.predict_lambert(normal, albedo, data, held), observed, valid)
    cap_train, surface = diligent_capture(data, lights=train)
    cap_held, _ = diligent_capture(data, lights=held)
    rows = []
    for model, loss in fits:
        t0 = time.perf_counter()
        f = relight.fit(cap_train, surface, model=model, normals=True, loss=loss)
        seconds = time.perf_counter() - t0
        err = ev.relative_rms(ev.predict_fit(f, cap_held, surface), observed, valid)
        row = dict(model=model, loss=loss, heldout=err, ratio=err / base, seconds=round(seconds, 1),
                   failed=float(np.mean(np.asarray(f.failed))),
                   model_fraction={m: float(np.mean(np.asarray(f.model) == i))
                                   for i, m in enumerate(relight.MODELS)})
        if data.normals_gt is not None:
            row["normal_mean_deg"] = float(np.mean(angular_error_deg(np.asarray(f.normal), data.normals_gt[data.mask])))
        rows.append(row)
        print(f"    {model:12s} {loss:7s} held-out {err:.4f} = {err / base:.2f}x baseline  ({seconds:.0f} s)",
              flush=True)
    out = dict(pixels=int(data.mask.sum()), held_out_observations=int(valid.sum()), baseline=base, fits=rows)
    if data.normals_gt is not None:
        out["baseline_normal_mean_deg"] = float(np.mean(angular_error_deg(normal, data.normals_gt[data.mask])))
    return out


def yaleb(fits, stride: int, subjects: list[str] | None) -> dict:
    import relight.evaluation as ev
    from relight.io import YALEB_DARK, read_yaleb

    root = DATA / "yaleb"
    names = subjects or sorted(p.name for p in root.glob("yaleB*") if p.is_dir())
    out = {}
    for name in names:
        d = read_yaleb(root / name)
        keep = np.zeros_like(d.mask)
        keep[::stride, ::stride] = True
        d = dataclasses.replace(d, mask=d.mask & keep)
        train, held = ev.heldout_split(len(d.filenames), 4, 3)
        print(f"  {name}: {int(d.mask.sum())} pixels, {len(train)} training / {len(held)} held-out lights", flush=True)
        out[name] = _score(d, train, held, fits, dark=YALEB_DARK, saturation=0.995, front_only=False,
                           baseline_valid=True)
    return out


def diligent(fits, objects: list[str]) -> dict:
    import relight.evaluation as ev
    from relight.io import read_diligent

    out = {}
    for name in objects:
        d = read_diligent(DATA / "diligent" / name)
        train, held = ev.heldout_split(len(d.filenames), 6, 3)
        print(f"  {name}: {int(d.mask.sum())} pixels, {len(train)} training / {len(held)} held-out lights", flush=True)
        out[name] = _score(d, train, held, fits, dark=0.0, saturation=0.995, front_only=True, baseline_valid=False)
    return out


def _markdown(report: dict) -> str:
    lines = [f"Machine: {report['machine']}. Command: `{report['command']}`.", ""]
    for section, items in report["sections"].items():
        if not items:
            continue
        pairs = [(r["model"], r["loss"]) for r in next(iter(items.values()))["fits"]]
        head = " | ".join(f"{m} / {loss}" for m, loss in pairs)
        lines += [f"### {section}: held-out relative RMS / the Lambertian baseline's", "",
                  f"| capture | pixels | held-out obs. | baseline | {head} |",
                  "|---|---|---|---|" + "---|" * len(pairs)]
        for name, it in items.items():
            cells = " | ".join(f"{r['ratio']:.2f}x" for r in it["fits"])
            obs = it["held_out_observations"]
            lines.append(f"| {name} | {it['pixels']} | {obs} | {it['baseline']:.4f} | {cells} |")
        ratios = np.array([[r["ratio"] for r in it["fits"]] for it in items.values()])
        lines.append("| **worst** | | | | " + " | ".join(f"**{v:.2f}x**" for v in ratios.max(0)) + " |")
        if "baseline_normal_mean_deg" in next(iter(items.values())):
            lines += ["", "Mean normal error (deg), training fit, every mask pixel:", "",
                      f"| capture | baseline | {head} |", "|---|---|" + "---|" * len(pairs)]
            for name, it in items.items():
                cells = " | ".join(f"{r['normal_mean_deg']:.2f}" for r in it["fits"])
                lines.append(f"| {name} | {it['baseline_normal_mean_deg']:.2f} | {cells} |")
        lines.append("")
    return "\n".join(lines)


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("--sections", default="yaleb,diligent")
    ap.add_argument("--models", default="lambert,blinn_phong,ggx,auto")
    ap.add_argument("--losses", default="cauchy,l2")
    ap.add_argument("--yaleb-stride", type=int, default=4, help="fit every k-th face pixel in x and y (default 4)")
    ap.add_argument("--subjects", default=None, help="comma-separated Yale B subjects (default: all)")
    ap.add_argument("--diligent", default="ballPNG,catPNG")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "figures")
    a = ap.parse_args(argv)
    fits = [(m, loss) for m in a.models.split(",") for loss in a.losses.split(",")]
    report = {"machine": machine(), "command": " ".join(["python scripts/eval_outside.py", *(argv or [])]),
              "sections": {}}
    t0 = time.perf_counter()
    for section in a.sections.split(","):
        if not (DATA / section).is_dir():
            print(f"{section}: {DATA / section} is absent; skipped")
            continue
        print(section, flush=True)
        if section == "yaleb":
            report["sections"]["yaleb"] = yaleb(fits, a.yaleb_stride, a.subjects.split(",") if a.subjects else None)
        elif section == "diligent":
            report["sections"]["diligent"] = diligent(fits, a.diligent.split(","))
        else:
            raise SystemExit(f"--sections: unknown section {section!r} (yaleb, diligent)")
    report["seconds"] = round(time.perf_counter() - t0, 1)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "outside.json").write_text(json.dumps(report, indent=1))
    (a.out / "outside.md").write_text(_markdown(report))
    print(_markdown(report))
    return report


if __name__ == "__main__":
    import sys

    main(sys.argv[1:])

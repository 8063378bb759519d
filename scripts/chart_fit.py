"""Speed against accuracy of ``relight.fit`` for each solver and model rung.

    python scripts/chart_fit.py                                  # 512 texels, the lean grid (11 fits)
    python scripts/chart_fit.py --grid full --texels 100000      # 10^5 texels, every solver x rung x normals
    python scripts/chart_fit.py --solvers lm,dogleg --models ggx --normals true

Scene as scripts/bench_fit.py (Light Stage X, 346 lights, 50 mm sphere,
cos_o >= 0.3, shading normals tilted 5 degrees from the start frame, 1% noise),
truth Lambert + isotropic GGX (alpha ~ U(0.1, 0.6)). Each rung is fitted to the
same capture, so the simpler rungs show their model error (Lambert cannot
explain the lobe; Blinn-Phong's exponent maps to alpha by s = 2 / alpha^2 - 2,
so its roughness error is partly the mapping), and without ``normals`` the
5-degree tilt stays in the fit.

Grid: "lean" (default) = LM on every rung with and without normals, and the
other solvers on ggx + normals; "full" = every solver x rung x normals; or
pick with --solvers / --models / --normals. Per configuration: one warm-up fit
on a ``--chunk``-sized subset with the same array shapes (it compiles), then the
timed fit of all ``--texels`` (compile time = warm-up time minus the subset's
share of the timed fit, approximately).

Writes docs/figures/fit_speed_accuracy.png, .md and .json (the rows). With
``--subsurface`` (default docs/figures/fit_subsurface_bench.json, written by
scripts/bench_fit_subsurface.py) a third panel puts the subsurface fit
(per-region, per-texel, the scipy baseline) on the same chart: its mean free
path error against its time. ``--replot`` redraws from the saved .json rows
without fitting.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import jax
import numpy as np
from _common import FIG, capture_of, errors, front_camera, machine, maxrss_mib, parser, sphere_surface, tilt, truth

import relight
import stage

RUNGS = ("lambert", "blinn_phong", "ggx", "ggx_aniso")


def configs(args):
    solvers = args.solvers.split(",") if args.solvers else list(relight.SOLVERS)
    models = args.models.split(",") if args.models else list(RUNGS)
    normals = {"both": (False, True), "true": (True,), "false": (False,)}[args.normals]
    if args.grid == "full" or args.solvers or args.models:
        return [(s, m, n) for s in solvers for m in models for n in normals]
    out = [("lm", m, n) for m in models for n in normals]
    out += [(s, "ggx", True) for s in solvers if s != "lm"]
    return out


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("--texels", type=int, default=512)
    ap.add_argument("--chunk", type=int, default=256)
    ap.add_argument("--grid", default="lean", choices=["lean", "full"])
    ap.add_argument("--solvers", default="")
    ap.add_argument("--models", default="")
    ap.add_argument("--normals", default="both", choices=["both", "true", "false"])
    ap.add_argument("--steps-per-round", type=int, default=20)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--noise", type=float, default=0.01)
    ap.add_argument("--out", default=str(FIG))
    ap.add_argument("--subsurface", default=str(FIG / "fit_subsurface_bench.json"),
                    help="rows of scripts/bench_fit_subsurface.py for the third panel ('' = none)")
    ap.add_argument("--replot", action="store_true", help="redraw from fit_speed_accuracy.json, no fitting")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.replot:
        doc = json.loads((out / "fit_speed_accuracy.json").read_text())
        plot(doc["rows"], doc["texels"], doc["noise"], out, args.subsurface)
        return
    t_start = time.perf_counter()

    rig = stage.light_stage_x()
    cam = front_camera()
    P = args.texels
    geo = sphere_surface(P, seed=20)
    true_surf = tilt(geo, 5.0, seed=21)
    rho, f0, alpha = truth(P, seed=22)
    cap = capture_of(true_surf, rig, cam, rho, f0, alpha, args.noise, seed=23)
    nrm = np.asarray(true_surf.normal)
    # Warm-up subset: chunk samples including the one with the most valid observations
    # (so the packed observation count, hence every shape, is the full fit's).
    nv = np.asarray(cap.mask).sum(axis=(0, 1))
    chunk = min(args.chunk, P)
    sub = np.unique(np.concatenate([[int(np.argmax(nv))], np.arange(chunk)]))[:chunk]
    if int(np.argmax(nv)) not in sub:
        sub[-1] = int(np.argmax(nv))
    sub = np.sort(sub)
    cap_sub = stage.Capture(cap.radiance[:, :, sub], cap.mask[:, :, sub], cap.rig, cap.cameras)
    geo_sub = geo.subset(sub)
    print(f"# machine: {machine()}")
    print(f"# {P} texels, Light Stage X, {args.noise:.0%} noise, chunk {chunk}, "
          f"{args.steps_per_round} x {args.rounds} steps")

    rows = []
    for sv, model, normals in configs(args):
        kw = dict(model=model, normals=normals, solver=sv,
                  options=relight.fitting.FitOptions(chunk=chunk, steps_per_round=args.steps_per_round,
                                                     rounds=args.rounds))
        t0 = time.perf_counter()
        relight.fit(cap_sub, geo_sub, **kw)
        t_warm = time.perf_counter() - t0
        t0 = time.perf_counter()
        f = relight.fit(cap, geo, **kw)
        jax.block_until_ready(f.rho_d)
        t = time.perf_counter() - t0
        er, ea, en = errors(f, rho, alpha, nrm)
        has_lobe = model != "lambert"
        row = dict(solver=sv, model=model, normals=normals, t=t, tps=P / t,
                   compile=max(t_warm - t * len(sub) / P, 0.0), e_rho=np.median(er),
                   e_alpha=np.median(ea) if has_lobe else np.nan, e_n=np.median(en),
                   failed=float(np.mean(np.asarray(f.failed))), steps=float(np.mean(np.asarray(f.steps))),
                   resid=float(np.median(np.asarray(f.residual))))
        rows.append(row)
        print(f"  {sv:6s} {model:11s} normals={normals!s:5s}: {t:7.1f} s ({row['tps']:.1f} texels/s), compile "
              f"~{row['compile']:.0f} s, albedo {row['e_rho']:.2%}, alpha {row['e_alpha']:.2%}, normal "
              f"{row['e_n']:.2f} deg, failed {row['failed']:.1%}, steps {row['steps']:.1f}", flush=True)

    lines = [f"Machine: {machine()}", "",
             f"`python scripts/chart_fit.py {' '.join(sys.argv[1:] if argv is None else argv)}`", "",
             f"{P} texels, Light Stage X (346 lights), {args.noise:.0%} noise, chunk {chunk}, "
             f"{args.steps_per_round} x {args.rounds} steps; truth Lambert + GGX, normals tilted 5 deg. "
             "Time excludes compilation (reported separately, approximate).", "",
             "| solver | model | normals | fit s | texels/s | compile s | median albedo err | median alpha err | "
             "median normal err (deg) | median RMS residual | failed | mean steps |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['solver']} | {r['model']} | {r['normals']} | {r['t']:.1f} | {r['tps']:.1f} | "
                     f"{r['compile']:.0f} | {r['e_rho']:.2%} | "
                     f"{'-' if np.isnan(r['e_alpha']) else format(r['e_alpha'], '.2%')} | {r['e_n']:.2f} | "
                     f"{r['resid']:.2e} | {r['failed']:.1%} | {r['steps']:.1f} |")
    md = "\n".join(lines) + (f"\n\nPeak RSS {maxrss_mib():.0f} MiB; "
                              f"total script time {time.perf_counter() - t_start:.0f} s.\n")
    print()
    print(md)
    (out / "fit_speed_accuracy.md").write_text(md)
    (out / "fit_speed_accuracy.json").write_text(json.dumps({"texels": P, "noise": args.noise, "rows": rows},
                                                             indent=2, default=float))
    plot(rows, P, args.noise, out, args.subsurface)


def plot(rows, P, noise, out: Path, subsurface: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sss = json.loads(Path(subsurface).read_text()) if subsurface and Path(subsurface).is_file() else None
    fig, axes = plt.subplots(1, 3 if sss else 2, figsize=(16.5 if sss else 11, 4.2))
    marks = dict(zip(RUNGS, "osD^", strict=False))
    cols = dict(zip(relight.SOLVERS, ("C0", "C1", "C2", "C3"), strict=False))
    for r in rows:
        kw = dict(marker=marks[r["model"]], color=cols[r["solver"]],
                  facecolors=cols[r["solver"]] if r["normals"] else "none", s=45)
        axes[0].scatter(r["t"], r["e_rho"], **kw)
        axes[1].scatter(r["t"], r["e_n"], **kw)
    for ax, lab in zip(axes[:2], ("median albedo error (relative)", "median normal error (deg)"), strict=True):
        ax.set_xlabel(f"seconds to fit {P} texels (2-core CPU, compile excluded)")
        ax.set_ylabel(lab)
        ax.set_yscale("log")
        ax.grid(alpha=0.3)
    hs = [plt.Line2D([], [], marker=marks[m], ls="", color="gray", label=m) for m in RUNGS]
    hs += [plt.Line2D([], [], marker="o", ls="", color=cols[s], label=s) for s in relight.SOLVERS]
    hs += [plt.Line2D([], [], marker="o", ls="", color="k", label="with normals"),
           plt.Line2D([], [], marker="o", ls="", mfc="none", color="k", label="without normals")]
    axes[1].legend(handles=hs, fontsize=7, loc="best")
    if sss:
        ax = axes[2]
        for k, r in enumerate(sss["rows"]):
            sec_per_k = 1000.0 / r["texels_per_s"]
            ax.scatter(sec_per_k, r["mfp_rel_identifiable"], marker="os^v"[k % 4], s=45, color=f"C{4 + k}",
                       label=r["name"])
        ax.set_xlabel("seconds per 1000 texels (warm)")
        ax.set_ylabel("median mean-free-path error (relative),\nover identifiable texel-channels")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6, loc="best")
        ax.set_title(f"relight.fit_subsurface: {sss['texels']} texels, {sss['lights']} lights", fontsize=9)
    fig.suptitle(f"relight.fit speed vs accuracy: Light Stage X, {P} texels, {noise:.0%} noise")
    fig.tight_layout()
    fig.savefig(out / "fit_speed_accuracy.png", dpi=120)
    print(f"wrote {out / 'fit_speed_accuracy.md'} and {out / 'fit_speed_accuracy.png'}")


if __name__ == "__main__":
    main()

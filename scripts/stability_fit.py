"""Stability sweep of ``relight.fit`` (Lambert + GGX + normal) for every solver.

    python scripts/stability_fit.py                          # 16, 100, 346 lights; all solvers
    python scripts/stability_fit.py --lights 16,40,100,346 --reps 8
    python scripts/stability_fit.py --solvers lm,dogleg

Samples: independent surface samples on a 20 mm planar patch at the centre of
the Light Stage X, seen by one camera 1 m in front, on a grid of
roughness (0.02 .. 1) x view cosine cos_o (1, 0.5, 0.2, 0.05: the shading
normal is turned away from the camera to reach it) x ``--reps`` random
albedos / F0 (F0 ~ U(0.02, 0.08)). The fit starts from a frame 3 degrees off
the true normal. Light counts: Light Stage X (346) and farthest-point subsets
of it (``rig.subset``). Conditions (one capture each, same shapes, so the
solver compiles once per solver and light count): noise 0, 1%, 5%
(multiplicative Gaussian), and "shadow": 1% noise with 30% of the valid
observations zeroed but left in the mask (unmasked cast shadows).

Per cell it reports the flagged failure rate (``Fit.failed``: a solve that did
not converge in the step budget, was rejected, or had too few observations),
the "wrong" rate (not flagged but albedo off by > 5%, normal by > 2 degrees, or,
for alpha >= 0.1, roughness by > 20%), and median errors. Roughness below the
rig's resolvable floor (``relight.rig_alpha_floor``: ~0.07 for 346 lights) is
expected to be reported at the floor and flagged ``unresolved``, not as a
failure. It asserts that no leaf of any Fit holds a NaN or an infinity.

Writes docs/figures/stability_fit_<solver>.png (heat maps: rows = failure
rate, wrong rate, median roughness error; columns = conditions over
roughness x light count, and one column over roughness x cos_o at the full
rig with 1% noise) and docs/figures/stability_fit.md (the table).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import jax
import numpy as np
from _common import FIG, capture_of, errors, front_camera, machine, make_surface, parser, tilt

import relight
import stage

ALPHAS = (0.02, 0.05, 0.1, 0.2, 0.35, 0.5, 0.7, 1.0)
COS_O = (1.0, 0.5, 0.2, 0.05)
CONDITIONS = (("noise 0", 0.0, 0.0), ("noise 1%", 0.01, 0.0), ("noise 5%", 0.05, 0.0), ("shadow 30%", 0.01, 0.3))


def farthest_subset(rig: stage.Rig, n: int) -> stage.Rig:
    """n lights of ``rig`` by farthest-point sampling of their directions (even coverage)."""
    if n >= rig.num_lights:
        return rig
    d = np.asarray(rig.directions, np.float64)
    pick = [int(np.argmax(d[:, 2]))]  # start at the light nearest the camera axis
    dist = 1 - d @ d[pick[0]]
    for _ in range(n - 1):
        k = int(np.argmax(dist))
        pick.append(k)
        dist = np.minimum(dist, 1 - d @ d[k])
    return rig.subset(np.sort(pick))


def grid_samples(reps: int, seed: int = 0):
    """Surface + truth on the roughness x cos_o x reps grid."""
    rng = np.random.default_rng(seed)
    A, C = np.meshgrid(np.asarray(ALPHAS), np.asarray(COS_O), indexing="ij")
    alpha = np.repeat(A.reshape(-1), reps)
    cos_o = np.repeat(C.reshape(-1), reps)
    P = len(alpha)
    phi = rng.uniform(0, 2 * np.pi, P)
    s = np.sqrt(1 - cos_o ** 2)
    normal = np.stack([s * np.cos(phi), s * np.sin(phi), cos_o], 1)
    g = int(np.ceil(np.sqrt(P)))
    xy = (np.stack(np.meshgrid(np.arange(g), np.arange(g)), -1).reshape(-1, 2)[:P] - g / 2) * (20.0 / g)
    pos = np.concatenate([xy, np.zeros((P, 1))], 1)
    true_surf = make_surface(pos, normal)
    start_surf = tilt(true_surf, 3.0, seed=seed + 1)
    rho = rng.uniform(0.1, 0.8, (P, 3))
    f0 = rng.uniform(0.02, 0.08, (P, 1))
    return true_surf, start_surf, rho, f0, alpha[:, None], cos_o


def assert_finite(f: relight.Fit, what: str):
    for path, leaf in jax.tree_util.tree_leaves_with_path(f):
        a = np.asarray(leaf)
        if a.dtype.kind in "fc" and not np.all(np.isfinite(a)):
            raise AssertionError(f"{what}: non-finite values in Fit{jax.tree_util.keystr(path)}")


def main(argv=None):  # noqa: C901 (a linear script: parse, simulate, fit, tabulate, plot)
    ap = parser(__doc__)
    ap.add_argument("--lights", default="16,100,346")
    ap.add_argument("--solvers", default=",".join(relight.SOLVERS))
    ap.add_argument("--reps", type=int, default=4, help="samples per (roughness, cos_o) cell")
    ap.add_argument("--steps-per-round", type=int, default=20)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out", default=str(FIG))
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    lights = [int(x) for x in args.lights.split(",")]
    solvers = args.solvers.split(",")
    t_start = time.perf_counter()

    lsx = stage.light_stage_x()
    cam = front_camera()
    true_surf, start_surf, rho, f0, alpha, cos_o = grid_samples(args.reps)
    P = true_surf.num_samples
    print(f"# machine: {machine()}")
    print(f"# {P} samples ({len(ALPHAS)} roughness x {len(COS_O)} cos_o x {args.reps}), lights {lights}, "
          f"solvers {solvers}, steps {args.steps_per_round} x {args.rounds} rounds")
    caps = {}
    for L in lights:
        rig = farthest_subset(lsx, L)
        caps[L] = (rig, [capture_of(true_surf, rig, cam, rho, f0, alpha, nz, seed=10 + i, shadow=sh)
                         for i, (_, nz, sh) in enumerate(CONDITIONS)])
    nrm = np.asarray(true_surf.normal)
    # res[solver][L][cond] = per-sample dict
    res = {}
    n_fits = 0
    for sv in solvers:
        res[sv] = {}
        for L in lights:
            rig, cl = caps[L]
            res[sv][L] = []
            for (name, _, _), cap in zip(CONDITIONS, cl, strict=False):
                t0 = time.perf_counter()
                f = relight.fit(cap, start_surf, model="ggx", normals=True, solver=sv,
                                options=relight.fitting.FitOptions(steps_per_round=args.steps_per_round,
                                                                   rounds=args.rounds))
                dt = time.perf_counter() - t0
                assert_finite(f, f"{sv} L={L} {name}")
                n_fits += 1
                er, ea, en = errors(f, rho, alpha, nrm)
                failed = np.asarray(f.failed)
                wrong = ~failed & ((er > 0.05) | (en > 2.0) | ((alpha[:, 0] >= 0.1) & (ea > 0.2)))
                res[sv][L].append(dict(er=er, ea=ea, en=en, failed=failed, wrong=wrong,
                                       unresolved=np.asarray(f.unresolved), floor=f.alpha_floor, t=dt))
                print(f"  {sv:6s} L={L:3d} {name:10s}: {dt:6.1f} s, failed {failed.mean():6.1%}, "
                      f"wrong {wrong.mean():6.1%}, median albedo {np.median(er):.2%}, "
                      f"alpha(>=0.1) {np.median(ea[alpha[:, 0] >= 0.1]):.2%}, normal {np.median(en):.2f} deg",
                      flush=True)
    print(f"no NaN or inf in any leaf of {n_fits} fits")

    # Table: per solver x condition x light count (all roughness, all cos_o).
    lines = ["| solver | lights | condition | failed | wrong | median albedo err | median alpha err (alpha >= 0.1) | "
             "median normal err (deg) | failed at cos_o = 0.05 | wrong at cos_o = 0.05 | fit s |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    graz = cos_o <= 0.05 + 1e-9
    ok_a = alpha[:, 0] >= 0.1
    for sv in solvers:
        for L in lights:
            for (name, _, _), r in zip(CONDITIONS, res[sv][L], strict=False):
                lines.append(f"| {sv} | {L} | {name} | {r['failed'].mean():.1%} | {r['wrong'].mean():.1%} | "
                             f"{np.median(r['er']):.2%} | {np.median(r['ea'][ok_a]):.2%} | {np.median(r['en']):.2f} | "
                             f"{r['failed'][graz].mean():.0%} | {r['wrong'][graz].mean():.0%} | {r['t']:.1f} |")
    table = "\n".join(lines)
    print()
    print(table)
    floors = {L: relight.rig_alpha_floor(caps[L][0]) for L in lights}
    md = out / "stability_fit.md"
    cmd = "python scripts/stability_fit.py " + " ".join(sys.argv[1:] if argv is None else argv)
    md.write_text(f"Machine: {machine()}\n\n`{cmd}`\n\n{P} samples per fit; roughness floors per light count: "
                  + ", ".join(f"{L}: {floors[L]:.3f}" for L in lights) + f"\n\n{table}\n\nNo NaN or inf in any leaf of "
                  f"{n_fits} fits.\n")

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ia = np.searchsorted(np.asarray(ALPHAS), alpha[:, 0])
    ic = np.array([COS_O.index(c) for c in cos_o])

    def cellmap(vals, rows_index, nrows):
        m = np.full((nrows, len(ALPHAS)), np.nan)
        for r in range(nrows):
            for a in range(len(ALPHAS)):
                sel = (rows_index == r) & (ia == a)
                if np.any(sel):
                    m[r, a] = vals(sel)
        return m

    metrics = (("failed (flagged)", lambda r: (lambda s: r["failed"][s].mean()), 0, 1, "Reds"),
               ("wrong (not flagged)", lambda r: (lambda s: r["wrong"][s].mean()), 0, 1, "Oranges"),
               ("median alpha error", lambda r: (lambda s: np.median(r["ea"][s])), 0, 0.5, "viridis"))
    for sv in solvers:
        ncol = len(CONDITIONS) + 1
        fig, axes = plt.subplots(len(metrics), ncol, figsize=(3.1 * ncol, 2.6 * len(metrics)), squeeze=False)
        for mi, (mname, fn, vmin, vmax, cmap) in enumerate(metrics):
            for ci, (cname, _, _) in enumerate(CONDITIONS):
                m = np.stack([cellmap(fn(res[sv][L][ci]), np.zeros(P, int), 1)[0] for L in lights])
                ax = axes[mi, ci]
                im = ax.imshow(m, origin="lower", aspect="auto", vmin=vmin, vmax=vmax, cmap=cmap)
                ax.set_yticks(range(len(lights)), [str(L) for L in lights])
                ax.set_xticks(range(len(ALPHAS)), [f"{a:g}" for a in ALPHAS], fontsize=6)
                for (y, x), v in np.ndenumerate(m):
                    ax.text(x, y, f"{v:.0%}" if mi < 2 else f"{v:.2f}", ha="center", va="center", fontsize=5,
                            color="w" if (v - vmin) / (vmax - vmin) > 0.5 else "k")
                if mi == 0:
                    ax.set_title(cname, fontsize=8)
                if ci == 0:
                    ax.set_ylabel(f"{mname}\nlights", fontsize=8)
                if mi == len(metrics) - 1:
                    ax.set_xlabel("roughness alpha", fontsize=7)
            # Grazing: roughness x cos_o, full rig, 1% noise.
            Lmax = max(lights)
            m = cellmap(fn(res[sv][Lmax][1]), ic, len(COS_O))
            ax = axes[mi, -1]
            ax.imshow(m, origin="lower", aspect="auto", vmin=vmin, vmax=vmax, cmap=cmap)
            ax.set_yticks(range(len(COS_O)), [f"{c:g}" for c in COS_O])
            ax.set_xticks(range(len(ALPHAS)), [f"{a:g}" for a in ALPHAS], fontsize=6)
            for (y, x), v in np.ndenumerate(m):
                ax.text(x, y, f"{v:.0%}" if mi < 2 else f"{v:.2f}", ha="center", va="center", fontsize=5,
                        color="w" if (v - vmin) / (vmax - vmin) > 0.5 else "k")
            ax.set_ylabel("cos_o", fontsize=7)
            if mi == 0:
                ax.set_title(f"{Lmax} lights, 1% noise, by view", fontsize=8)
            fig.colorbar(im, ax=axes[mi].tolist(), shrink=0.8)
        fig.suptitle(f"relight.fit solver={sv}: Lambert+GGX+normal, {P} samples per fit", fontsize=10)
        fig.savefig(out / f"stability_fit_{sv}.png", dpi=110)
        plt.close(fig)
    print(f"wrote {md} and stability_fit_<solver>.png for {solvers}; total {time.perf_counter() - t_start:.0f} s")


if __name__ == "__main__":
    main()

"""Benchmark ``relight.fit`` (Lambert + GGX + normal, Light Stage X) against a
``scipy.optimize.least_squares`` loop over the same texels, in the same run.

    python scripts/bench_fit.py                          # 1024 texels, scipy on 256 of them
    python scripts/bench_fit.py --texels 16384 --scipy-texels 1024
    python scripts/bench_fit.py --chunks 128,512,2048 --steps 5,10,20,40

Scene: a sphere of radius 50 mm at the centre of the Light Stage X (346
near-field lights), one camera 1 m in front; samples on the camera-facing
hemisphere with cos_o >= 0.3 (a convex sphere: no cast shadows; the mask
holds lit, seen and front-facing observations). Truth: rho_d ~ U(0.1, 0.8)^3,
F0 ~ U(0.02, 0.08), alpha ~ U(0.1, 0.6), the shading normal tilted 5 degrees
from the geometric one in a random azimuth (the fit starts from the geometric
frame, photometric stereo then moves it). Radiance x (1 + 0.01 N(0, 1)).

Ours: ``relight.fit(capture, surface, model="ggx", normals=True)`` (Cauchy
loss) for every (solver, chunk, steps_per_round) setting asked for: solver
"lm" (the default, ``relight.fitting.NormalLevenbergMarquardt``) and
"optx-lm" (``optimistix.LevenbergMarquardt``, the default before), with
``rounds`` = 60 / steps_per_round (the same 60-step budget per sample); one
untimed warm-up call per setting on a chunk-sized subset with the same array
shapes compiles (its wall time minus the subset's share of the timed call is
reported as the compile time), then ``--repeat`` timed calls of which the
fastest counts (scipy likewise), so another process's load spike biases
neither side of the ratio. Throughput = texels / wall time of
the whole ``fit`` call (observation packing, start, solve, uncertainties).

Reference: ``scipy.optimize.least_squares`` (MINPACK ``lm``, 2-point finite
difference Jacobian), one call per texel, same objective (the same forward
model written in numpy: Lambert + GGX with separable Smith G1, Schlick F,
(a, b, 1) normal chart, sigmoid transforms, the same square-rooted Cauchy
residual with the same scale), the same start (relight's photometric-stereo +
roughness-grid start, ``relight.fitting.start_parameters``, under JAX), the
same valid observations (``relight.fitting.observations``), on a random subset of ``--scipy-texels`` of the
texels. Its throughput is that subset's texels / seconds. Accuracies
(median relative albedo and roughness error, median normal angle error) are
reported for ours on all texels and for both on the common subset.

Peak memory: ``ru_maxrss`` of the process (whole process: JAX, the capture,
compiled code) after each stage.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import jax
import numpy as np
from _common import FIG, capture_of, errors, front_camera, machine, maxrss_mib, parser, sphere_surface, tilt, truth

import relight
import stage

# --------------------------------------------------------------------------- the numpy / scipy reference

def np_predict(u, wi, wo, irr, floor):
    """relight's ggx + normal rung in numpy (float64): u = logit rho_d[3], logit F0,
    logit((alpha - floor) / (1 - floor)), a, b; wi, wo [N, 3] in the surface frame."""
    sig = lambda x: 1.0 / (1.0 + np.exp(-x))  # noqa: E731
    rho = sig(u[0:3])
    f0 = sig(u[3])
    al = floor + (1.0 - floor) * sig(u[4])
    n = np.array([u[5], u[6], 1.0])
    n /= np.linalg.norm(n)
    # Fitted frame: surface tangent (1,0,0) projected off n, b = n x t (relight's fitted frame, phi = 0).
    t = np.array([1.0, 0.0, 0.0]) - n[0] * n
    t /= np.linalg.norm(t)
    b = np.cross(n, t)
    R = np.stack([t, b, n])
    wif, wof = wi @ R.T, wo @ R.T
    zi, zo = wif[:, 2], wof[:, 2]
    lit = (zi > 0) & (zo > 0)
    h = wif + wof
    h /= np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-12)
    a2 = al * al
    tD = (h[:, 0] ** 2 + h[:, 1] ** 2) / a2 + h[:, 2] ** 2
    D = np.where(h[:, 2] > 0, 1.0 / (np.pi * a2 * tD * tD), 0.0)
    c = np.clip(np.sum(wif * h, 1), 0.0, 1.0)
    F = f0 + (1 - f0) * (1 - c) ** 5
    zis, zos = np.where(zi > 0, zi, 1.0), np.where(zo > 0, zo, 1.0)
    g1i = 2.0 / (zis + np.sqrt(a2 * (wif[:, 0] ** 2 + wif[:, 1] ** 2) + zis * zis))
    g1o = 2.0 / (zos + np.sqrt(a2 * (wof[:, 0] ** 2 + wof[:, 1] ** 2) + zos * zos))
    spec = D * F * 0.25 * g1i * g1o
    f = np.where(lit[:, None], rho[None] / np.pi + spec[:, None], 0.0)
    return f * np.maximum(zi, 0.0)[:, None] * irr


def np_residual(u, obs, wi, wo, irr, floor, c):
    r = (np_predict(u, wi, wo, irr, floor) - obs).reshape(-1)
    if c is None:
        return r
    y = (r / c) ** 2
    small = y < 1e-6
    ys = np.where(small, 1.0, y)
    return r * np.where(small, 1.0 - 0.25 * y, np.sqrt(np.log1p(ys) / ys))


def packed_data(capture, surface, lay):
    """relight's per-sample observation arrays and its start u0 (relight.fitting.observations and
    relight.fitting.start_parameters)."""
    obs = relight.fitting.observations(capture, surface, dtype=np.float32)
    u0 = np.asarray(relight.fitting.start_parameters(obs, lay))
    return obs.radiance, obs.weight, obs.wi, obs.wo, obs.irradiance, u0


def scipy_fit(idx, data, floor, cauchy=0.1, method="lm"):
    """One scipy.optimize.least_squares per texel; returns u [n, 7], nfev [n], seconds."""
    from scipy.optimize import least_squares

    obs, w, wi, wo, irr, u0 = data
    out = np.zeros((len(idx), u0.shape[1]))
    nfev = np.zeros(len(idx), int)
    t0 = time.perf_counter()
    for j, p in enumerate(idx):
        v = w[p, :, 0] > 0
        o, a, b, e = (np.asarray(x[p][v], np.float64) for x in (obs, wi, wo, irr))
        scale = np.sqrt(np.sum(o * o) / max(o.size, 1))
        c = None if cauchy is None else cauchy * scale + 1e-12
        sol = least_squares(np_residual, np.asarray(u0[p], np.float64), method=method, args=(o, a, b, e, floor, c),
                            xtol=1e-8, ftol=1e-8, gtol=1e-8, max_nfev=2000 if method != "lm" else None)
        out[j], nfev[j] = sol.x, sol.nfev
    return out, nfev, time.perf_counter() - t0


def u_to_physical(u, surface, floor, idx):
    """scipy's u for the samples idx -> (rho_d [n, 3], alpha [n], normal [n, 3] world)."""
    sig = lambda x: 1.0 / (1.0 + np.exp(-x))  # noqa: E731
    rho = sig(u[:, 0:3])
    al = floor + (1 - floor) * sig(u[:, 4])
    nl = np.concatenate([u[:, 5:7], np.ones((len(u), 1))], 1)
    nl /= np.linalg.norm(nl, axis=1, keepdims=True)
    T, B, N = (np.asarray(x, np.float64)[idx] for x in (surface.tangent, surface.bitangent, surface.normal))
    n = nl[:, :1] * T + nl[:, 1:2] * B + nl[:, 2:3] * N
    return rho, al, n


# --------------------------------------------------------------------------- the benchmark

def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("--texels", type=int, default=1024)
    ap.add_argument("--scipy-texels", type=int, default=256)
    ap.add_argument("--scipy-method", default="lm", choices=["lm", "trf"])
    ap.add_argument("--chunks", default="128,512", help="comma list of chunk sizes")
    ap.add_argument("--steps", default="10,20", help="comma list of steps_per_round")
    ap.add_argument("--rounds", type=int, default=0, help="rounds (0: enough for 60 steps per sample)")
    ap.add_argument("--noise", type=float, default=0.01)
    ap.add_argument("--solvers", default="lm,optx-lm", help="comma list of relight.fit solver names")
    ap.add_argument("--repeat", type=int, default=3,
                    help="timed calls per setting (and of scipy); the fastest is reported, so load spikes from "
                         "other processes bias neither side of the ratio")
    ap.add_argument("--out", default=str(FIG))
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    rig = stage.light_stage_x()
    cam = front_camera()
    geo = sphere_surface(args.texels, seed=0)
    true_surf = tilt(geo, 5.0, seed=1)
    rho, f0, alpha = truth(args.texels, seed=3)
    t0 = time.perf_counter()
    cap = capture_of(true_surf, rig, cam, rho, f0, alpha, args.noise, seed=4)
    print(f"# machine: {machine()}")
    print(f"# scene: {args.texels} texels, Light Stage X ({rig.num_lights} lights), "
          f"{float(np.mean(np.sum(np.asarray(cap.mask), axis=(0, 1)))):.0f} valid lights per texel on average, "
          f"{args.noise:.0%} noise; simulated in {time.perf_counter() - t0:.1f} s; maxrss {maxrss_mib():.0f} MiB")
    normal_true = np.asarray(true_surf.normal)

    rows = []
    best = None
    settings = [(sv, int(c), int(s)) for sv in args.solvers.split(",") for c in args.chunks.split(",")
                for s in args.steps.split(",")]
    for solver, chunk, spr in settings:
        rounds = args.rounds or max(1, -(-60 // spr))
        kw = dict(model="ggx", normals=True, solver=solver,
                  options=relight.fitting.FitOptions(chunk=chunk, steps_per_round=spr, rounds=rounds))
        # Warm-up on chunk samples including the one with the most valid observations
        # (the packed observation count, hence every shape, is the full fit's): compiles.
        nv = np.asarray(cap.mask).sum(axis=(0, 1))
        sub = np.arange(min(chunk, args.texels))
        if int(np.argmax(nv)) not in sub:
            sub[-1] = int(np.argmax(nv))
        t0 = time.perf_counter()
        relight.fit(stage.Capture(cap.radiance[:, :, sub], cap.mask[:, :, sub], cap.rig, cap.cameras),
                    geo.subset(sub), **kw)
        t_first = time.perf_counter() - t0
        t = np.inf
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            f = relight.fit(cap, geo, **kw)
            jax.block_until_ready(f.rho_d)
            t = min(t, time.perf_counter() - t0)
        er, ea, en = errors(f, rho, alpha, normal_true)
        row = dict(solver=solver, chunk=chunk, spr=spr, rounds=rounds, t=t,
                   compile=max(t_first - t * len(sub) / args.texels, 0.0),
                   tps=args.texels / t, e_rho=np.median(er), e_alpha=np.median(ea), e_n=np.median(en),
                   failed=float(np.mean(np.asarray(f.failed))), steps=float(np.mean(np.asarray(f.steps))),
                   rss=maxrss_mib(), fit=f)
        rows.append(row)
        print(f"  ours {solver:8s} chunk={chunk:5d} steps/round={spr:3d} rounds={rounds}: {t:7.2f} s, "
              f"{row['tps']:8.1f} texels/s, compile {row['compile']:.1f} s, failed {row['failed']:.2%}, "
              f"mean steps {row['steps']:.1f}", flush=True)
        if best is None or t < best["t"]:
            best = row

    # scipy on a random subset, same start, same objective.
    from relight.materials import GGX

    floor = relight.rig_alpha_floor(rig)
    lay = relight.fitting.Layout(GGX, True, floor)
    data = packed_data(cap, geo, lay)
    rng = np.random.default_rng(5)
    idx = np.sort(rng.choice(args.texels, min(args.scipy_texels, args.texels), replace=False))
    t_sp = np.inf
    for _ in range(args.repeat):
        u_sp, nfev, t_once = scipy_fit(idx, data, floor, method=args.scipy_method)
        t_sp = min(t_sp, t_once)
    rss_sp = maxrss_mib()
    rho_sp, al_sp, n_sp = u_to_physical(u_sp, geo, floor, idx)
    er_sp = np.mean(np.abs(rho_sp - rho[idx]) / rho[idx], 1)
    ea_sp = np.abs(al_sp - alpha[idx, 0]) / alpha[idx, 0]
    en_sp = np.rad2deg(np.arccos(np.clip(np.sum(n_sp * normal_true[idx], 1), -1, 1)))
    tps_sp = len(idx) / t_sp
    # The start alone (what both refine from).
    rho0, al0, n0 = u_to_physical(np.asarray(data[5][idx], np.float64), geo, floor, idx)
    er0 = np.mean(np.abs(rho0 - rho[idx]) / rho[idx], 1)
    ea0 = np.abs(al0 - alpha[idx, 0]) / alpha[idx, 0]
    en0 = np.rad2deg(np.arccos(np.clip(np.sum(n0 * normal_true[idx], 1), -1, 1)))

    bf = best["fit"]
    er_b, ea_b, en_b = (x[idx] for x in errors(bf, rho, alpha, normal_true))

    lines = ["| method | chunk | steps/round x rounds | texels | wall s | texels/s | compile s | ratio vs scipy | "
             "median albedo err | median alpha err | median normal err (deg) | failed | peak RSS MiB |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| relight.fit {r['solver']} | {r['chunk']} | {r['spr']} x {r['rounds']} | {args.texels} | "
                     f"{r['t']:.2f} | "
                     f"{r['tps']:.1f} | {r['compile']:.1f} | {r['tps'] / tps_sp:.1f}x | {r['e_rho']:.3%} | "
                     f"{r['e_alpha']:.2%} | {r['e_n']:.3f} | {r['failed']:.2%} | {r['rss']:.0f} |")
    lines.append(f"| scipy least_squares {args.scipy_method} (2-point J) | 1 | until converged | {len(idx)} | "
                 f"{t_sp:.2f} | {tps_sp:.1f} | 0 | 1.0x | {np.median(er_sp):.3%} | {np.median(ea_sp):.2%} | "
                 f"{np.median(en_sp):.3f} | - | {rss_sp:.0f} |")
    table = "\n".join(lines)
    same = ["| on the scipy subset | median albedo err | median alpha err | median normal err (deg) | "
            "90th pct normal err |", "|---|---|---|---|---|",
            f"| start (photometric stereo + alpha grid) | {np.median(er0):.3%} | {np.median(ea0):.2%} | "
            f"{np.median(en0):.3f} | {np.percentile(en0, 90):.3f} |",
            f"| relight.fit (best setting) | {np.median(er_b):.3%} | {np.median(ea_b):.2%} | {np.median(en_b):.3f} | "
            f"{np.percentile(en_b, 90):.3f} |",
            f"| scipy least_squares | {np.median(er_sp):.3%} | {np.median(ea_sp):.2%} | {np.median(en_sp):.3f} | "
            f"{np.percentile(en_sp, 90):.3f} |"]
    same = "\n".join(same)
    print()
    print(table)
    print()
    print(same)
    nfev_line = (f"scipy: mean {np.mean(nfev):.1f} residual evaluations outside the finite-difference Jacobians "
                 "(MINPACK nfev, about one per iteration; each Jacobian adds 7) per texel")
    print("\n" + nfev_line)
    print(f"best: {best['solver']} chunk={best['chunk']} steps/round={best['spr']}: {best['tps']:.1f} texels/s = "
          f"{best['tps'] / tps_sp:.1f}x scipy ({tps_sp:.1f} texels/s); goal >= 10x")
    md = out / "fit_bench.md"
    cmd = " ".join(sys.argv[1:] if argv is None else argv)
    md.write_text(f"Machine: {machine()}\n\n`python scripts/bench_fit.py {cmd}`\n\n{table}\n\n{same}\n\n{nfev_line}.\n")

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for r in rows:
        ax.scatter(r["tps"], r["e_n"], c="C0" if r["solver"] == "lm" else "C1")
        ax.annotate(f"{r['chunk']}/{r['spr']}", (r["tps"], r["e_n"]), fontsize=7)
    ax.scatter(tps_sp, np.median(en_sp), c="C3", marker="s", label=f"scipy {args.scipy_method}")
    ax.scatter([], [], c="C0", label="relight.fit lm (chunk/steps per round)")
    ax.scatter([], [], c="C1", label="relight.fit optx-lm (optx.LevenbergMarquardt)")
    ax.set_xscale("log")
    ax.set_xlabel("texels / s (2-core CPU)")
    ax.set_ylabel("median normal error (deg)")
    ax.set_title(f"Lambert+GGX+normal, {rig.num_lights} lights, {args.noise:.0%} noise")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "fit_bench.png", dpi=120)
    print(f"wrote {md} and {out / 'fit_bench.png'}")


if __name__ == "__main__":
    main()

"""Benchmark ``relight.fit`` (Lambert + GGX + normal, Light Stage X) against a
``scipy.optimize.least_squares`` loop over the same texels, in the same run.

    python scripts/bench_fit.py                          # 1024 texels, scipy on 256 of them
    python scripts/bench_fit.py --texels 16384 --scipy-texels 1024
    python scripts/bench_fit.py --chunks 128,512,2048 --steps 5,10,20,40
    python scripts/bench_fit.py --ceres-jacobian autodiff --ceres-linear qr,cholesky --ceres-loss sqrt,cauchy

Scene: a sphere of radius 50 mm at the centre of the Light Stage X (346
near-field lights), one camera 1 m in front; samples on the camera-facing
hemisphere with cos_o >= 0.3 (a convex sphere: no cast shadows; the mask
holds lit, seen and front-facing observations). Truth: rho_d ~ U(0.1, 0.8)^3,
F0 ~ U(0.02, 0.08), alpha ~ U(0.1, 0.6), the shading normal tilted 5 degrees
from the geometric one in a random azimuth (the fit starts from the geometric
frame, photometric stereo then moves it). Radiance x (1 + 0.01 N(0, 1)).

Ours: ``relight.fit(capture, surface, model="ggx", normals=True, loss="cauchy")``
for every (solver, chunk, steps_per_round) setting asked for: solver
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
reported for ours on all texels and for each baseline on the common subset.

Reference: Ceres 2.1 (Debian's ``libceres-dev``; without it the line is skipped
with how to install it), ``scripts/ceres_fit.cc`` compiled here with g++ -O3
-march=native once per run (``scripts/_ceres.py``): the same problem (the numpy
model above, term for term: the run checks Ceres's cost against numpy's at the
start and at the solution), the same starts and valid observations, one
``ceres::Problem`` per texel solved by Levenberg-Marquardt (at most 60 steps, or
until Ceres's tolerances stop it), texels spread over ``--ceres-threads``
threads (default: the cores). One row per (``--ceres-loss``, ``--ceres-jacobian``,
``--ceres-linear``) setting: the square-rooted Cauchy residual in one residual
block, or ``ceres::CauchyLoss`` on one block per observation and channel;
automatic derivatives (Jet<double, 7>) or a structured Jacobian (closed-form
albedo columns, dual numbers for the lobe only: what relight's does); dense QR
or dense normal-equations Cholesky. Its throughput is ``--ceres-texels`` (all by
default, at least the scipy subset) / the C++ solve time (std::chrono; the
files, the process start and the starts are outside it, where ours counts its
packing and start); the wall time with the file exchange is printed beside it.

Texels per CPU second: texels / the process's CPU seconds in the same timed
calls (ours and scipy: ``time.process_time``; Ceres: its process CPU clock
around the solve), all threads; less moved by other users of a shared machine
than the wall time. ``--phases``: our best setting's phases (packing, start,
solve, uncertainties) re-run one by one through relight.fitting's public
per-sample problems (:func:`our_phases`), to say where our time goes.

Peak memory: ``ru_maxrss`` of the process (whole process: JAX, the capture,
compiled code) after each stage.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import _ceres
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


def texel_problem(p, data, floor, cauchy=0.1):
    """Texel p's valid observations (float64) and Cauchy scale: np_residual's arguments after u."""
    obs, w, wi, wo, irr, _ = data
    v = w[p, :, 0] > 0
    o, a, b, e = (np.asarray(x[p][v], np.float64) for x in (obs, wi, wo, irr))
    scale = np.sqrt(np.sum(o * o) / max(o.size, 1))
    return o, a, b, e, floor, None if cauchy is None else cauchy * scale + 1e-12


def scipy_fit(idx, data, floor, cauchy=0.1, method="lm"):
    """One scipy.optimize.least_squares per texel; returns u [n, 7], nfev [n], seconds, CPU seconds."""
    from scipy.optimize import least_squares

    u0 = data[5]
    out = np.zeros((len(idx), u0.shape[1]))
    nfev = np.zeros(len(idx), int)
    t0, c0 = time.perf_counter(), time.process_time()
    for j, p in enumerate(idx):
        sol = least_squares(np_residual, np.asarray(u0[p], np.float64), method=method,
                            args=texel_problem(p, data, floor, cauchy),
                            xtol=1e-8, ftol=1e-8, gtol=1e-8, max_nfev=2000 if method != "lm" else None)
        out[j], nfev[j] = sol.x, sol.nfev
    return out, nfev, time.perf_counter() - t0, time.process_time() - c0


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


def physical_errors(u, surface, floor, idx, rho, alpha, normal):
    """Per-texel errors of u [n, 7] for the samples idx: relative albedo (mean over RGB), relative
    roughness, normal angle (deg)."""
    r, a, n = u_to_physical(u, surface, floor, idx)
    return (np.mean(np.abs(r - rho[idx]) / rho[idx], 1), np.abs(a - alpha[idx, 0]) / alpha[idx, 0],
            np.rad2deg(np.arccos(np.clip(np.sum(n * normal[idx], 1), -1, 1))))


def ceres_fits(args, data, idx, floor, surface, rho, alpha, normal):
    """The Ceres rows: compile scripts/ceres_fit.cc once, then solve the Ceres texels (``--ceres-texels``,
    0 = all; always including the scipy subset idx) for each (loss, jacobian, linear) setting, fastest of
    ``--repeat``. Returns (texel indices, rows, compile seconds); no rows where Ceres is not installed."""
    P = len(data[5])
    n = P if args.ceres_texels <= 0 else min(max(args.ceres_texels, len(idx)), P)
    rest = np.setdiff1d(np.arange(P), idx)
    cidx = np.sort(np.concatenate([idx, np.random.default_rng(6).choice(rest, n - len(idx), replace=False)]))
    settings = [(lo, jac, lin) for lo in args.ceres_loss.split(",") for jac in args.ceres_jacobian.split(",")
                for lin in args.ceres_linear.split(",") if lo == "sqrt" or jac == "autodiff"]
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_fit_ceres_") as tmp:
        exe, t_cc, why = _ceres.build(Path(tmp))
        if exe is None:
            print(f"# Ceres rows skipped: {why}")
            return cidx, rows, 0.0
        print(f"# Ceres: compiled {_ceres.SOURCE.name} in {t_cc:.1f} s (g++ -O3 -march=native)")
        arrays = tuple(np.asarray(x)[cidx] for x in data)
        at = np.searchsorted(cidx, idx)  # the scipy subset's rows among the Ceres texels
        for loss, jac, lin in settings:
            r = _ceres.solve(exe, arrays, floor, repeat=args.repeat, threads=args.ceres_threads or None, loss=loss,
                             linear=lin, jacobian=jac)
            # Ceres's cost (0.5 sum r^2) against the numpy reference's at the start and at the solution.
            ref = [(0.5 * np.sum(np_residual(np.asarray(data[5][p], np.float64), *texel_problem(p, data, floor)) ** 2),
                    0.5 * np.sum(np_residual(r["u"][j], *texel_problem(p, data, floor)) ** 2))
                   for p, j in zip(idx, at, strict=True)]
            ref = np.asarray(ref)
            dcost = np.max(np.abs(np.stack([r["cost0"][at], r["cost"][at]], 1) - ref) / ref, axis=0)
            err = physical_errors(r["u"], surface, floor, cidx, rho, alpha, normal)
            name = (f"Ceres {r['version']} LM ({jac}, dense {'QR' if lin == 'qr' else 'Cholesky'}"
                    f"{', CauchyLoss' if loss == 'cauchy' else ''}), C++ -O3, {r['threads']} threads")
            row = dict(name=name, n=len(cidx), t=r["solve_s"], wall=r["wall_s"], tps=len(cidx) / r["solve_s"],
                       tpc=len(cidx) / r["cpu_s"],
                       e_rho=np.median(err[0]), e_alpha=np.median(err[1]), e_n=np.median(err[2]),
                       sub=tuple(e[at] for e in err), failed=1 - np.mean(r["converged"]),
                       iters=np.mean(r["iterations"]), dcost=dcost, phases=r["phases"])
            rows.append(row)
            ph = row["phases"]
            split = ", ".join(f"{k} {ph[k] / ph['solve']:.0%}" for k in _ceres.PHASES[1:])
            print(f"  {name}: {row['t']:.2f} s, {row['tps']:.1f} texels/s (wall with the file exchange "
                  f"{row['wall']:.2f} s), mean {row['iters']:.1f} iterations, not converged {row['failed']:.2%}; "
                  f"cost vs numpy: max rel diff {dcost[0]:.1e} at the start, {dcost[1]:.1e} at the solution; "
                  f"Ceres's time: {split}", flush=True)
    return cidx, rows, t_cc


def our_phases(capture, surface, lay, chunk, steps, repeat):
    """Where relight.fit's time goes, its phases re-run one by one through relight.fitting's public
    per-sample problems on the same texels, in chunks of ``chunk`` (padded, as the fit does): packing
    (``observations``), start (``start_parameters``), solve (``solve_samples``: ``steps`` LM steps, then the
    accept test and the uncertainties: the fit's first round) and that call with 1 step (the uncertainties
    and each call's fixed cost, plus one step). Fastest of ``repeat`` after one compiling call; seconds."""
    from relight.fitting import Observations, observations, solve_samples, start_parameters

    def timed(fn):
        jax.block_until_ready(fn())
        t = np.inf
        for _ in range(repeat):
            t0 = time.perf_counter()
            jax.block_until_ready(fn())
            t = min(t, time.perf_counter() - t0)
        return t

    out = dict(packing=timed(lambda: observations(capture, surface).radiance))
    obs = observations(capture, surface)
    P = len(obs.radiance)
    parts = [Observations(*(x[np.resize(np.arange(s, min(s + chunk, P)), chunk)] for x in obs[:5]))
             for s in range(0, P, chunk)]
    out["start"] = timed(lambda: [start_parameters(p, lay) for p in parts])
    u0 = [start_parameters(p, lay) for p in parts]
    for name, k in ((f"solve ({steps} steps + uncertainties)", steps), ("solve (1 step + uncertainties)", 1)):
        out[name] = timed(lambda k=k: [solve_samples(u, p, lay, max_steps=k, cauchy=0.1)[:5]
                                       for u, p in zip(u0, parts, strict=True)])
    return out


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
    ap.add_argument("--ceres-texels", type=int, default=0,
                    help="texels for Ceres (0: all; at least the scipy subset); -1: no Ceres rows")
    ap.add_argument("--ceres-loss", default="sqrt", help="comma list: sqrt (the square-rooted Cauchy residual, "
                    "as numpy), cauchy (ceres::CauchyLoss, one block per observation and channel)")
    ap.add_argument("--ceres-jacobian", default="autodiff,structured", help="comma list: autodiff, structured")
    ap.add_argument("--ceres-linear", default="qr,cholesky", help="comma list: qr, cholesky (dense)")
    ap.add_argument("--ceres-threads", type=int, default=0, help="Ceres's threads (0: the cores)")
    ap.add_argument("--phases", action="store_true",
                    help="also time our fit's phases (packing, start, solve) one by one at the best setting")
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
        kw = dict(model="ggx", normals=True, solver=solver, loss="cauchy",
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
        t = cpu = np.inf
        for _ in range(args.repeat):
            t0, c0 = time.perf_counter(), time.process_time()
            f = relight.fit(cap, geo, **kw)
            jax.block_until_ready(f.rho_d)
            t, cpu = min(t, time.perf_counter() - t0), min(cpu, time.process_time() - c0)
        er, ea, en = errors(f, rho, alpha, normal_true)
        row = dict(solver=solver, chunk=chunk, spr=spr, rounds=rounds, t=t, cpu=cpu,
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
    t_sp = cpu_sp = np.inf
    for _ in range(args.repeat):
        u_sp, nfev, t_once, cpu_once = scipy_fit(idx, data, floor, method=args.scipy_method)
        t_sp, cpu_sp = min(t_sp, t_once), min(cpu_sp, cpu_once)
    rss_sp = maxrss_mib()
    er_sp, ea_sp, en_sp = physical_errors(u_sp, geo, floor, idx, rho, alpha, normal_true)
    tps_sp = len(idx) / t_sp
    # The start alone (what all refine from).
    er0, ea0, en0 = physical_errors(np.asarray(data[5][idx], np.float64), geo, floor, idx, rho, alpha, normal_true)
    # Ceres on all texels (or --ceres-texels of them, the scipy subset among them).
    cidx, ce_rows, t_cc = ceres_fits(args, data, idx, floor, geo, rho, alpha, normal_true) \
        if args.ceres_texels >= 0 else (None, [], 0.0)
    tps_ce = max((r["tps"] for r in ce_rows), default=np.nan)
    tpc_ce = max((r["tpc"] for r in ce_rows), default=np.nan)

    bf = best["fit"]
    er_b, ea_b, en_b = (x[idx] for x in errors(bf, rho, alpha, normal_true))

    vs = lambda tps: f"{tps / tps_ce:.2f}x" if ce_rows else "-"  # noqa: E731
    lines = ["| method | chunk | steps/round x rounds | texels | wall s | texels/s | texels/CPU s | compile s | "
             "ratio vs scipy | ratio vs fastest Ceres | median albedo err | median alpha err | "
             "median normal err (deg) | failed | peak RSS MiB |", "|---" * 15 + "|"]
    acc_cells = lambda r: f"{r['e_rho']:.3%} | {r['e_alpha']:.2%} | {r['e_n']:.3f}"  # noqa: E731
    for r in rows:
        lines.append(f"| relight.fit {r['solver']} | {r['chunk']} | {r['spr']} x {r['rounds']} | {args.texels} | "
                     f"{r['t']:.2f} | {r['tps']:.1f} | {args.texels / r['cpu']:.1f} | {r['compile']:.1f} | "
                     f"{r['tps'] / tps_sp:.1f}x | {vs(r['tps'])} | {acc_cells(r)} | {r['failed']:.2%} | "
                     f"{r['rss']:.0f} |")
    sp = dict(e_rho=np.median(er_sp), e_alpha=np.median(ea_sp), e_n=np.median(en_sp))
    lines.append(f"| scipy least_squares {args.scipy_method} (2-point J) | 1 | until converged | {len(idx)} | "
                 f"{t_sp:.2f} | {tps_sp:.1f} | {len(idx) / cpu_sp:.1f} | 0 | 1.0x | {vs(tps_sp)} | {acc_cells(sp)} | "
                 f"- | {rss_sp:.0f} |")
    for r in ce_rows:
        lines.append(f"| {r['name']} | 1 | <= 60, mean {r['iters']:.1f} | {r['n']} | {r['t']:.2f} | {r['tps']:.1f} | "
                     f"{r['tpc']:.1f} | {t_cc:.1f} (g++) | {r['tps'] / tps_sp:.1f}x | {vs(r['tps'])} | "
                     f"{acc_cells(r)} | {r['failed']:.2%} | - |")
    table = "\n".join(lines)
    acc = lambda name, er, ea, en: (f"| {name} | {np.median(er):.3%} | {np.median(ea):.2%} | "  # noqa: E731
                                    f"{np.median(en):.3f} | {np.percentile(en, 90):.3f} |")
    same = ["| on the scipy subset | median albedo err | median alpha err | median normal err (deg) | "
            "90th pct normal err |", "|---|---|---|---|---|",
            acc("start (photometric stereo + alpha grid)", er0, ea0, en0),
            acc("relight.fit (best setting)", er_b, ea_b, en_b), acc("scipy least_squares", er_sp, ea_sp, en_sp),
            *(acc(r["name"], *r["sub"]) for r in ce_rows)]
    same = "\n".join(same)
    print()
    print(table)
    print()
    print(same)
    nfev_line = (f"scipy: mean {np.mean(nfev):.1f} residual evaluations outside the finite-difference Jacobians "
                 "(MINPACK nfev, about one per iteration; each Jacobian adds 7) per texel")
    notes = [nfev_line]
    if args.phases:
        ph = our_phases(cap, geo, lay, best["chunk"], best["spr"], args.repeat)
        notes.append(f"relight.fit {best['solver']} chunk={best['chunk']} ({best['t']:.2f} s), its phases re-run one "
                     "by one (public per-sample problems, fastest of --repeat): "
                     + ", ".join(f"{k} {v:.2f} s" for k, v in ph.items()))
    for r in ce_rows:
        ph = r["phases"]
        notes.append(f"{r['name']}: wall {r['wall']:.2f} s with the file exchange and the process start "
                     f"(solve {r['t']:.2f} s); cost against numpy's, max relative difference {r['dcost'][0]:.1e} "
                     f"at the start, {r['dcost'][1]:.1e} at the solution; Ceres's time: "
                     + ", ".join(f"{k} {ph[k] / ph['solve']:.0%}" for k in _ceres.PHASES[1:]))
    print("\n" + "\n".join(notes))
    ce_best = (f", {best['tps'] / tps_ce:.2f}x the fastest Ceres ({tps_ce:.1f} texels/s on {os.cpu_count()} cores; "
               f"per CPU second {args.texels / best['cpu'] / tpc_ce:.2f}x)" if ce_rows else "")
    print(f"best: {best['solver']} chunk={best['chunk']} steps/round={best['spr']}: {best['tps']:.1f} texels/s = "
          f"{best['tps'] / tps_sp:.1f}x scipy ({tps_sp:.1f} texels/s){ce_best}; goals >= 10x scipy, >= 1x Ceres")
    md = out / "fit_bench.md"
    cmd = " ".join(sys.argv[1:] if argv is None else argv)
    md.write_text(f"Machine: {machine()}\n\n`python scripts/bench_fit.py {cmd}`\n\n{table}\n\n{same}\n\n"
                  + "".join(f"{n}.\n\n" for n in notes).rstrip() + "\n")

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for r in rows:
        ax.scatter(r["tps"], r["e_n"], c="C0" if r["solver"] == "lm" else "C1")
        ax.annotate(f"{r['chunk']}/{r['spr']}", (r["tps"], r["e_n"]), fontsize=7)
    ax.scatter(tps_sp, np.median(en_sp), c="C3", marker="s", label=f"scipy {args.scipy_method}")
    for i, r in enumerate(ce_rows):
        ax.scatter(r["tps"], r["e_n"], c=f"C{4 + i}", marker="^", label=r["name"].split(", C++")[0])
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

"""Speed and accuracy of ``relight.fit_subsurface``: per-region against
per-texel mean free path, with a scipy baseline measured in the same run.

    python scripts/bench_fit_subsurface.py                       # 490 texels, 42 lights
    python scripts/bench_fit_subsurface.py --texel-res 48 --dome 2 --scipy-texels 60
    python scripts/bench_fit_subsurface.py --float32                # JAX's default float, as the CLI

Scene as tests/relight/test_fit_sss_texel.py: a 6 mm sphere's camera-facing
texels (``--texel-res`` 32: 490 texels, spacing 0.59 mm), a geodesic dome
(``--dome`` 1: 42 lights), GGX specular + Burley subsurface with three areas
of true mean free path (by x: 0.5, 1, 3 mm in red; x 0.7 green, x 0.5 blue),
1% noise, simulated and fitted with a 5 mm operator radius. Prints, per rung:
the time of a warm call (a first call compiles), texels/s, and the median
relative mfp error over all texels and over the identifiable ones (the texel
fit's 1-sigma of ln mfp < 0.25). Baseline: ``scipy.optimize.least_squares``
(trust-region reflective, bounds on ln mfp and albedo) per texel and channel
on the same reduced data (``relight.fitting.subsurface_texel_data``), residual
and prior, on ``--scipy-texels`` texels; its texels/s and its agreement with
the vmapped LM there. Last, the alternative data reduction: the Gram matrix
G^T diag(a) G of a chunk of ``--chunk`` texels against the gathered irradiance
G the LM uses (its size, and the time to form it from G).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import jax

# float64 as the tests (default) or, with --float32, JAX's default float as the CLI runs.
jax.config.update("jax_enable_x64", "--float32" not in sys.argv)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _common import parser, uv_sphere  # noqa: E402
from scipy.optimize import least_squares  # noqa: E402

import brdf  # noqa: E402
import relight  # noqa: E402
import skin_bssrdf  # noqa: E402
import stage  # noqa: E402

RADIUS_MM = 5.0


def scene(res, dome, seed=0):
    mesh = uv_sphere(radius=6.0, n_lat=24, n_lon=48)
    surface = stage.texel_samples(mesh, res)
    rig = stage.geodesic_dome(dome)
    cam = stage.look_at((0.0, 0.0, 400.0), fov_deg=4, width=64, height=64)
    lv = stage.light_visibility(mesh, surface, rig)
    cv = stage.camera_visibility(mesh, surface, [cam])
    keep = np.nonzero(cv[0])[0]
    surface, lv, cv = surface.subset(keep), lv[keep], cv[:, keep]
    P = surface.num_samples
    area = np.digitize(np.asarray(surface.position)[:, 0], [-2.0, 2.0])
    truth = np.array([0.5, 1.0, 3.0])[area][:, None] * np.array([1.0, 0.7, 0.5])[None]
    dt = surface.position.dtype
    A = jnp.broadcast_to(jnp.array([0.8, 0.6, 0.45]), (P, 3))
    spec = brdf.Microfacet(brdf.GGX(jnp.full((P, 1), 0.3, dt)), brdf.SchlickFresnel(jnp.full((P, 1), 0.03, dt)),
                           "smith")
    prof = skin_bssrdf.Burley.from_mean_free_path(A, jnp.asarray(truth), config="dmfp")
    op = skin_bssrdf.DiffusionOperator.build(np.asarray(surface.position), np.asarray(surface.area), RADIUS_MM)
    cap = stage.simulate(surface, rig, [cam], spec, lv, cv,
                         subsurface=stage.Subsurface(prof, op, skin_bssrdf.SKIN_ETA))
    eps = 1 + 0.01 * np.random.default_rng(seed).standard_normal(cap.radiance.shape)
    cap = stage.Capture(cap.radiance * jnp.asarray(eps, cap.radiance.dtype), cap.mask, cap.rig, cap.cameras)
    return surface, cap, truth, op


def timed(fn, repeat=1):
    fn()  # compile
    t = time.perf_counter()
    for _ in range(repeat):
        out = fn()
    return out, (time.perf_counter() - t) / repeat


def scipy_texels(surface, cap, fitted, region, texels, op, lo=0.05, hi=8.0):
    """(ln mfp [n, C], seconds): scipy least_squares per texel and channel, the LM's residual and prior."""
    td = relight.fitting.subsurface_texel_data(cap, surface, fitted, op, texels)
    a, ybar, c0, cnt = td.weight, td.exitance, td.constant, td.count
    Gs, Gn, r_nb, rho = td.self_irradiance, td.neighbour_irradiance, td.distance, td.self_radius
    prior = np.log(np.asarray(region.mfp))[texels]
    A0 = np.asarray(region.rho_d)[texels]
    out = np.zeros((len(texels), 3))
    t = time.perf_counter()
    for i in range(len(texels)):
        n = float(np.sum(cnt[i]))
        for c in range(3):
            sw = np.sqrt(a[i])
            floor = td.noise_floor[i, c]

            def res(x, i=i, c=c, sw=sw, n=n, floor=floor):
                ln_m, A = x
                d = np.exp(ln_m) / (3.5 + 100 * (A - 0.33) ** 4)
                rr = np.maximum(r_nb[i], 1e-6 * d)
                w = (np.exp(-rr / d) + np.exp(-rr / (3 * d))) / (8 * np.pi * d * rr)
                ws = 1 - 0.25 * np.exp(-rho[i] / d) - 0.75 * np.exp(-rho[i] / (3 * d))
                S = Gs[i, c] * ws + Gn[i, c] @ w
                rd = sw * (A * S - ybar[i, :, c])
                s2 = (np.sum(rd * rd) + np.sum(c0[i, :, c])) / max(n - 2.0, 1.0) + floor
                return np.concatenate([rd, [np.sqrt(s2) * (ln_m - prior[i, c]) / relight.fitting.PRIOR_SIGMA_LN_MFP]])

            x0 = [np.clip(prior[i, c], np.log(lo) + 1e-6, np.log(hi) - 1e-6), np.clip(A0[i, c], 1e-3, 1 - 1e-3)]
            sol = least_squares(res, x0, bounds=([np.log(lo), 0.0], [np.log(hi), 1.0]), method="trf", xtol=1e-10)
            out[i, c] = sol.x[0]
    return out, time.perf_counter() - t


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("--texel-res", type=int, default=32)
    ap.add_argument("--dome", type=int, default=1)
    ap.add_argument("--scipy-texels", type=int, default=40)
    ap.add_argument("--chunk", type=int, default=128,
                    help="texels of the gathered-irradiance / Gram comparison (the texel solve's chunk on the "
                         "default scene)")
    ap.add_argument("--float32", action="store_true", help="run JAX in float32 (x64 off)")
    ap.add_argument("--json", default=str(Path(__file__).resolve().parent.parent / "docs" / "figures" /
                                          "fit_subsurface_bench.json"),
                    help="where to write the rows (read by scripts/chart_fit.py --subsurface; '' = nowhere)")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    surface, cap, truth, op = scene(args.texel_res, args.dome)
    P, L = surface.num_samples, cap.rig.num_lights
    fitted = relight.fit(cap, surface)
    print(f"scene: {P} texels, {L} lights, K = {op.index.shape[1]} neighbours within {RADIUS_MM} mm, "
          f"setup {time.perf_counter() - t0:.1f} s; jax {jax.__version__}, {jax.devices()[0].platform}, "
          f"{jnp.result_type(float)}")
    region, t_region = timed(lambda: relight.fit_subsurface(cap, surface, fitted, radius_mm=RADIUS_MM))
    phase = {}

    def clock(name, done, total):
        # Seconds from a phase's first report to its last (the texel solve, without the region start).
        now = time.perf_counter()
        phase.setdefault(name, [now, now])[1] = now

    def texel_fit():
        phase.clear()
        return relight.fit_subsurface(cap, surface, fitted, per="texel", radius_mm=RADIUS_MM, progress=clock)

    texel, t_texel = timed(texel_fit)
    t_solve = phase["fit subsurface texels"][1] - phase["fit subsurface texels"][0]
    ident = np.asarray(texel.mfp_identified)
    rows = []
    for name, g, t in (("per-region (grid + golden section)", region, t_region),
                       ("per-texel (vmapped optx Dogleg), incl. its region start", texel, t_texel),
                       ("per-texel: the texel solve alone", texel, t_solve)):
        rel = np.abs(np.asarray(g.mfp) - truth) / truth
        rows.append((name, t, P / t, np.median(rel), np.median(rel[ident]), np.median(rel[truth >= 1.5])))
    rng = np.random.default_rng(1)
    sub = np.sort(rng.choice(P, min(args.scipy_texels, P), replace=False))
    ln_sp, t_sp = scipy_texels(surface, cap, fitted, region, sub, op)
    rel_sp = np.abs(np.exp(ln_sp) - truth[sub]) / truth[sub]
    rows.append((f"scipy least_squares per texel-channel ({len(sub)} texels; errors over them)", t_sp, len(sub) / t_sp,
                 np.median(rel_sp), np.median(rel_sp[ident[sub]]), np.median(rel_sp[truth[sub] >= 1.5])))
    print("\n| rung | seconds (warm) | texels/s | median rel. mfp error | identifiable | true mfp >= 1.5 mm |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    for name, t, rate, e_all, e_id, e_big in rows:
        print(f"| {name} | {t:.2f} | {rate:.0f} | {e_all:.3f} | {e_id:.3f} | {e_big:.3f} |")
    if args.json:
        import json
        import platform

        doc = {"command": "python scripts/bench_fit_subsurface.py " + " ".join(sys.argv[1:] if argv is None else argv),
               "machine": f"{platform.machine()}, {os.cpu_count()} cores, jax {jax.__version__} "
                          f"({jax.devices()[0].platform}), {jnp.result_type(float)}",
               "texels": P, "lights": L, "identifiable_fraction": float(ident.mean()),
               "rows": [dict(name=n, seconds=t, texels_per_s=r, mfp_rel_median=e, mfp_rel_identifiable=i,
                             mfp_rel_true_ge_1p5mm=b) for n, t, r, e, i, b in rows]}
        Path(args.json).write_text(json.dumps(doc, indent=2, default=float))
        print(f"wrote {args.json}")
    agree = np.abs(ln_sp - np.log(np.asarray(texel.mfp))[sub])
    print(f"\nidentifiable texel-channels: {ident.mean():.1%} (per channel {np.round(ident.mean(0), 3)}); "
          f"scipy vs the optx solve on the subset: median |d ln mfp| {np.median(agree):.2e}, "
          f"over identifiable {np.median(agree[ident[sub]]):.2e}")
    # The data reduction: gathered irradiance [n, C, L, K + 1] (what the LM keeps) against the Gram [n, C, K+1, K+1].
    K = op.index.shape[1]
    n = min(args.chunk, P)
    td = relight.fitting.subsurface_texel_data(cap, surface, fitted, op, np.arange(n))
    G = jnp.concatenate([jnp.asarray(td.self_irradiance)[..., None], jnp.asarray(td.neighbour_irradiance)], -1)
    aj = jnp.asarray(td.weight)
    gram = jax.jit(lambda G, a: jnp.einsum("ncla,nl,nclb->ncab", G, a, G))
    (_, t_h) = timed(lambda: jax.block_until_ready(gram(G, aj)), 3)
    b = np.dtype(jnp.result_type(float)).itemsize
    print(f"\ndata per chunk of {n} texels: gathered irradiance {n * 3 * L * (K + 1) * b / 2**20:.1f} MiB; "
          f"Gram G^T diag(a) G {n * 3 * (K + 1) ** 2 * b / 2**20:.1f} MiB, {t_h * 1e3:.1f} ms more to form from it "
          f"(and an LM on it would need its Cholesky factor, K^3 per texel-channel)")
    print(f"total {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()

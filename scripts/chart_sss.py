"""Speed against accuracy of subsurface scattering on the head scan.

For the Lee Perry-Smith head (../shared/data/meshes) at a few texel
resolutions, times and errors of: no subsurface (albedo x irradiance), the
texture-space sum of Gaussians (d'Eon et al. 2007), and the sparse 3-D kernel
with each profile. The material is Jensen et al. 2001's skin1; the reference is
the better dipole (d'Eon 2012) integrated with the sparse kernel over a fine
sampling (texels of a 512^2 atlas, radius holding 99.9 % of the energy),
evaluated at (up to 1500) samples of each resolution. Approximations of the
reference profile: the classical dipole with the same coefficients, Burley's
normalised diffusion from (albedo, diffuse mean free path) with the paper's dmfp
fit, and a six-Gaussian fit (sparse and texture-space).

Irradiance: a distant white light from the upper right, cosine-weighted and
striped (a projected 15 mm pattern) so that shadow edges exercise the diffusion.
Error: relative RMS over the evaluation samples and channels,
||M - M_ref|| / ||M_ref||. Time: the median of 3 jitted runs of the diffusion
step alone (ms, float32, this machine's CPU); the per-geometry neighbour search
is reported separately.

Usage: python scripts/chart_sss.py [--resolutions 64 128 256] [--out docs/figures/sss_speed_accuracy.png]
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _common import parser, save_figure

import skin_bssrdf as sb
import stage

ROOT = Path(__file__).resolve().parents[1]
MESH = ROOT.parent / "shared" / "data" / "meshes" / "lee_perry_smith_head.glb"
DOC = ROOT / "docs" / "skin_bssrdf.md"
BEGIN, END = "<!-- chart_sss:begin -->", "<!-- chart_sss:end -->"


def irradiance(surf) -> np.ndarray:
    pos = np.asarray(surf.position, np.float64)
    n = np.asarray(surf.normal, np.float64)
    light = np.array([0.6, 0.5, 0.62])
    light /= np.linalg.norm(light)
    stripes = 0.25 + 0.75 * (np.sin(2 * np.pi * pos[:, 1] / 15.0) > 0)
    e = np.clip(n @ light, 0, None) * stripes
    return np.repeat(e[:, None], 3, axis=1)


def timed(fn, *args, repeats=3):
    out = jax.block_until_ready(fn(*args))  # compile + warm up
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        out = jax.block_until_ready(fn(*args))
        ts.append(time.perf_counter() - t)
    return np.asarray(out), 1e3 * float(np.median(ts))


def reference(fine, profile, eval_pos, radius):
    """Sparse-kernel exitance at arbitrary points: the points join the fine samples as receivers
    with a negligible area (1e-9 mm^2), so they add nothing as sources."""
    fpos = np.asarray(fine.position, np.float64)
    pos = np.concatenate([fpos, eval_pos])
    area = np.concatenate([np.asarray(fine.area, np.float64), np.full(len(eval_pos), 1e-9)])
    E = np.concatenate([irradiance(fine), np.zeros((len(eval_pos), 3))])
    recv = np.arange(len(fpos), len(pos))
    ops = sb.DiffusionOperator.build(pos, area, radius, receivers=recv)
    return np.asarray(ops.apply(profile, jnp.asarray(E, jnp.float32)))


def rel_rms(a, b):
    return float(np.sqrt(np.mean((a - b) ** 2)) / np.sqrt(np.mean(b**2)))


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("--resolutions", type=int, nargs="+", default=[64, 128, 256])
    ap.add_argument("--reference-resolution", type=int, default=512)
    ap.add_argument("--eval", type=int, default=1500, help="evaluation samples per resolution")
    ap.add_argument("--out", default=str(ROOT / "docs" / "figures" / "sss_speed_accuracy.png"))
    ap.add_argument("--no-doc", action="store_true", help="do not rewrite the table in docs/skin_bssrdf.md")
    args = ap.parse_args(argv)
    if not MESH.is_file():
        print(f"chart_sss: head scan not found at {MESH}", file=sys.stderr)
        return 2

    mesh = stage.load_mesh(MESH, scale=stage.HEAD_SCALE_MM, center=True)
    f32 = jnp.float32
    m = sb.JENSEN2001["skin1"]
    sa, ss, eta = (jnp.asarray(x, f32) for x in (m.sigma_a, m.sigma_s_prime, m.eta))
    ref_profile = sb.BetterDipole(sa, ss, eta)
    albedo, dmfp = sb.albedo_from_coefficients(sa, ss, eta, model="better_dipole")
    profiles = {
        "better dipole": ref_profile,
        "dipole": sb.Dipole(sa, ss, eta),
        "Burley (dmfp fit)": sb.Burley.from_mean_free_path(albedo, dmfp, "dmfp"),
    }
    sog64 = sb.fit_sum_of_gaussians(ref_profile, n=6)
    sog = sb.SumOfGaussians(jnp.asarray(sog64.weights, f32), jnp.asarray(sog64.variances, f32))
    profiles["sum of Gaussians"] = sog

    fine = stage.texel_samples(mesh, args.reference_resolution)
    ref_radius = float(np.max(np.asarray(sb.energy_radius(ref_profile, 0.999))))
    print(f"reference: {fine.num_samples} samples at {args.reference_resolution}^2, radius {ref_radius:.1f} mm")
    rng = np.random.default_rng(0)
    rows = []
    for res in args.resolutions:
        surf = stage.texel_samples(mesh, res)
        P = surf.num_samples
        pick = np.sort(rng.choice(P, size=min(args.eval, P), replace=False))
        pos = np.asarray(surf.position, np.float64)
        t = time.perf_counter()
        M_ref = reference(fine, ref_profile, pos[pick], ref_radius)
        t_ref = time.perf_counter() - t
        E = jnp.asarray(irradiance(surf), f32)
        spacing = float(np.sqrt(np.median(np.asarray(surf.area))))
        print(f"\n{res}^2: {P} samples, spacing {spacing:.2f} mm (reference at {len(pick)} of them: {t_ref:.1f} s)")
        # no subsurface: the local albedo times the irradiance
        none = jax.jit(lambda E: E * ref_profile.total()[None])
        out, ms = timed(none, E)
        rows.append((res, P, "no subsurface", ms, 0.0, rel_rms(out[pick], M_ref)))
        # texture space
        t = time.perf_counter()
        tsd = sb.TextureSpaceDiffusion.build(surf.texel_index, surf.resolution, pos, dtype=f32)
        t_build = time.perf_counter() - t
        out, ms = timed(jax.jit(lambda tsd, E: tsd.apply(sog, E)), tsd, E)
        rows.append((res, P, "texture-space sum of Gaussians", ms, t_build * 1e3, rel_rms(out[pick], M_ref)))
        # sparse kernel with each profile
        for name, prof in profiles.items():
            radius = sb.operator_radius(prof)
            t = time.perf_counter()
            ops = sb.DiffusionOperator.build(pos, np.asarray(surf.area), radius, dtype=f32)
            t_build = time.perf_counter() - t
            # the operator is an argument, not a closure: its arrays must not become XLA constants
            out, ms = timed(jax.jit(lambda ops, E, prof=prof: ops.apply(prof, E)), ops, E)
            rows.append((res, P, f"sparse kernel, {name}", ms, t_build * 1e3, rel_rms(out[pick], M_ref)))
            del ops
        for r in rows[-2 - len(profiles) :]:
            print(f"  {r[2]:<36s} {r[3]:9.1f} ms  (setup {r[4]:8.0f} ms)  error {100 * r[5]:6.2f} %")

    table = _table(rows, fine.num_samples, args.reference_resolution, ref_radius)
    print("\n" + table)
    _chart(rows, args.out)
    print(f"\nwrote {args.out}")
    if not args.no_doc and DOC.is_file():
        _write_table(table)
        print(f"updated the table in {DOC}")
    return 0


def _table(rows, n_ref, ref_res, ref_radius):
    lines = [
        f"Reference: better dipole (skin1), sparse kernel over {n_ref} samples ({ref_res}^2 texels), "
        f"radius {ref_radius:.1f} mm (99.9 % of the energy). "
        "Time: diffusion step, float32, median of 3, this machine's CPU.",
        "",
        "| texels | samples | method | time (ms) | setup (ms) | rel. RMS error |",
        "| ---: | ---: | --- | ---: | ---: | ---: |",
    ]
    for res, P, name, ms, setup, err in rows:
        lines.append(f"| {res}^2 | {P} | {name} | {ms:.1f} | {setup:.0f} | {100 * err:.2f} % |")
    return "\n".join(lines)


def _chart(rows, out):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5))
    methods = sorted({r[2] for r in rows}, key=lambda n: [r[2] for r in rows].index(n))
    markers = "osD^vP*X"
    for k, name in enumerate(methods):
        rr = [r for r in rows if r[2] == name]
        x = [max(r[3], 1e-2) for r in rr]
        y = [100 * r[5] for r in rr]
        ax.plot(x, y, "-" + markers[k % len(markers)], label=name)
        for r, xi, yi in zip(rr, x, y, strict=False):
            ax.annotate(f"{r[0]}", (xi, yi), textcoords="offset points", xytext=(4, 3), fontsize=7)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("time per diffusion step (ms, float32 CPU)")
    ax.set_ylabel("relative RMS error vs fine better-dipole reference (%)")
    ax.set_title("Subsurface scattering on the head scan: error against time\n(labels: texture resolution)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, out, dpi=120)
    plt.close(fig)


def _write_table(table):
    text = DOC.read_text()
    if BEGIN in text and END in text:
        a, b = text.index(BEGIN) + len(BEGIN), text.index(END)
        text = text[:a] + "\n" + table + "\n" + text[b:]
    else:
        text += f"\n{BEGIN}\n{table}\n{END}\n"
    tmp = DOC.with_name(DOC.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, DOC)


if __name__ == "__main__":
    sys.exit(main())

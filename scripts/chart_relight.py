"""Model-based relighting methods: error against a converged Monte Carlo
reference versus time, for the head scan under every environment map.

    python scripts/chart_relight.py   # 32 x 32 texels (950 samples), 8192-spp reference, ~10 min on 2 cores
    python scripts/chart_relight.py --texels 16 --ref-samples 1024   # quicker (a smoke run)

Writes docs/figures/relight_methods.png and docs/figures/relight_methods.md
(and prints the table). Material: GGX alpha 0.3, F0 0.04 over a skin-like
Lambert base (0.6, 0.42, 0.33), no subsurface; view from a camera 700 mm in
front of the head; error = relative RMS over the samples that face the camera,
sqrt(mean (x - ref)^2 / mean ref^2) over RGB. The reference is method
"reference" at --ref-samples samples per sample (power-heuristic MIS); its own
noise is estimated from a second independent run and reported.

Times are wall-clock milliseconds of one ``render_samples`` call with the JIT
compiled (a warm-up call per map resolution is not timed). "rig" and "dense"
are given their visibility masks (computed once per geometry and reused for
every map; that one-off cost is listed separately); "lights" casts the
shadow rays of its median-cut lights, "fast" its ambient-occlusion rays and
"reference" its shadow rays inside the timed call.
"""

from __future__ import annotations

import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _common import parser, save_figure

import relight
import stage
from relight import render
from relight.envmap import latlong_directions, load_envmap

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data" / "envmaps"
BUNDLED = ROOT / "relight" / "data"


def envmaps():
    maps = sorted(SHARED.glob("*.hdr"))
    out = [(p.stem, p) for p in maps]
    for p in sorted(BUNDLED.glob("*.hdr")):
        same = [n for n, q in out if q.name == p.name and q.read_bytes() == p.read_bytes()]
        out.append((f"bundled {p.stem}" + (" (= shared)" if same else ""), p))
    return out


def settings():
    dome = {s: stage.geodesic_dome(s) for s in (2, 3, 4)}
    rows = [("rig", "Light Stage X (346, near field)", {"rig": stage.light_stage_x()})]
    rows += [("rig", f"geodesic dome {r.num_lights}", {"rig": r}) for r in dome.values()]
    rows += [("dense", f"{r} x {2 * r}", {"resolution": r}) for r in (16, 32, 64)]
    rows += [("lights", f"median cut {k}", {"lights": k}) for k in (64, 256, 1024)]
    rows += [("fast", "SH2 + split-sum + AO 64", {})]
    rows += [("reference", f"{n} spp", {"samples": n}) for n in (16, 64, 256)]
    return rows


def rel_rmse(x, ref, mask):
    x, ref = np.asarray(x, np.float64)[mask], np.asarray(ref, np.float64)[mask]
    return float(np.sqrt(np.mean((x - ref) ** 2) / np.mean(ref**2)))


def main():
    ap = parser(__doc__)
    ap.add_argument("--texels", type=int, default=32)
    ap.add_argument("--ref-samples", type=int, default=8192)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "figures" / "relight_methods")
    args = ap.parse_args()

    t_start = time.perf_counter()
    mesh = stage.load_head()
    surf = stage.texel_samples(mesh, args.texels)
    P = surf.num_samples
    maps = relight.material_maps(surf, np.array([0.6, 0.42, 0.33]), 0.04, 0.3)
    cam = stage.look_at((0.0, 0.0, 700.0), fov_deg=30, width=256, height=256)
    wo = cam.view_directions(surf.position)
    mask = np.sum(np.asarray(wo) * np.asarray(surf.normal), axis=1) > 0
    rows = settings()
    print(f"head: {P} texel samples ({args.texels}^2 grid), {mask.sum()} facing the camera")

    # Visibility once per geometry (reused by every map).
    vis, vis_ms = {}, {}
    for method, name, kw in rows:
        if method == "rig":
            t = time.perf_counter()
            vis[name] = stage.light_visibility(mesh, surf, kw["rig"], packed=True)
            vis_ms[name] = 1e3 * (time.perf_counter() - t)
        elif method == "dense":
            r = kw["resolution"]
            d = np.asarray(latlong_directions(r, 2 * r, jnp.float32)).reshape(-1, 3)
            rig = stage.Rig(position=jnp.asarray(d * 1e3), intensity=jnp.ones((len(d), 1)),
                            solid_angle=jnp.full((len(d),), 4 * np.pi / len(d)), near_field=False)
            t = time.perf_counter()
            vis[name] = stage.light_visibility(mesh, surf, rig, packed=True)
            vis_ms[name] = 1e3 * (time.perf_counter() - t)
    print("visibility (one-off, ms):", {k: round(v) for k, v in vis_ms.items()})

    results = {}  # (map, setting) -> (err, ms)
    ref_noise = {}
    seen_shapes = set()
    names = []
    cache = {}
    for name, path in envmaps():
        names.append(name)
        if "(= shared)" in name:  # byte-identical to a shared map: same numbers
            src = path.stem
            for k in [k for k in results if k[0] == src]:
                results[(name, k[1])] = results[k]
            ref_noise[name] = ref_noise[src]
            continue
        env = load_envmap(path)
        t = time.perf_counter()
        ref = render.render_samples(maps, surf, env, wo, method="reference", mesh=mesh, samples=args.ref_samples,
                                    key=jax.random.PRNGKey(1))
        ref = np.asarray(ref)
        ref_ms = 1e3 * (time.perf_counter() - t)
        ref2 = np.asarray(render.render_samples(maps, surf, env, wo, method="reference", mesh=mesh,
                                                samples=args.ref_samples // 4, key=jax.random.PRNGKey(2)))
        # Noise of the reference: a run with 1/4 of the samples has twice its standard error.
        ref_noise[name] = rel_rmse(ref2, ref, mask) / np.sqrt(1 + 4)
        cache[name] = ref
        warm = env.radiance.shape not in seen_shapes
        seen_shapes.add(env.radiance.shape)
        for method, label, kw in rows:
            kw = dict(kw)
            if method in ("rig", "dense"):
                kw["visibility"] = vis[label]
            else:
                kw["mesh"] = mesh
            if method == "reference":
                kw["key"] = jax.random.PRNGKey(7)
            if warm:
                jax.block_until_ready(render.render_samples(maps, surf, env, wo, method=method, **kw))
            t = time.perf_counter()
            out = jax.block_until_ready(render.render_samples(maps, surf, env, wo, method=method, **kw))
            ms = 1e3 * (time.perf_counter() - t)
            results[(name, f"{method}: {label}")] = (rel_rmse(out, ref, mask), ms)
        print(f"{name}: reference {args.ref_samples} spp in {ref_ms:.0f} ms, its noise ~{ref_noise[name]:.4f}; "
              f"elapsed {time.perf_counter() - t_start:.0f} s")

    labels = [f"{m}: {lab}" for m, lab, _ in rows]
    # Markdown table: error per map, median time.
    lines = [f"Head scan, {P} texel samples ({args.texels}^2 grid), {int(mask.sum())} facing the camera; "
             f"reference: {args.ref_samples} spp MIS. Error: relative RMS vs the reference. "
             "Time: median over maps of one warm call (ms).", "",
             "| method: setting | " + " | ".join(names) + " | time (ms) | visibility one-off (ms) |",
             "| --- | " + " | ".join("---" for _ in names) + " | --- | --- |"]
    for lab, (_m, l2, _) in zip(labels, rows, strict=False):
        errs = [results[(n, lab)][0] for n in names]
        ms = float(np.median([results[(n, lab)][1] for n in names]))
        vo = f"{vis_ms[l2]:.0f}" if l2 in vis_ms else "-"
        lines.append(f"| {lab} | " + " | ".join(f"{e:.4f}" for e in errs) + f" | {ms:.0f} | {vo} |")
    lines.append("| reference noise (est.) | " + " | ".join(f"{ref_noise[n]:.4f}" for n in names) + " | | |")
    table = "\n".join(lines)
    print(table)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    md = args.out.with_suffix(".md")
    tmp = md.with_name(md.name + ".tmp")
    tmp.write_text(f"<!-- generated by scripts/chart_relight.py --texels {args.texels} --ref-samples "
                   f"{args.ref_samples} -->\n\n" + table + "\n")
    tmp.replace(md)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ncol = 4
    nrow = -(-len(names) // ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.6 * nrow), squeeze=False)
    colors = {"rig": "tab:blue", "dense": "tab:orange", "lights": "tab:purple", "fast": "tab:green",
              "reference": "tab:red"}
    markers = ["o", "s", "^", "D"]
    for ax, n in zip(axes.ravel(), names, strict=False):
        count = {}
        for lab, (m, _l2, _) in zip(labels, rows, strict=False):
            e, ms = results[(n, lab)]
            i = count.get(m, 0)
            count[m] = i + 1
            ax.loglog(ms, max(e, 1e-5), markers[i % 4], color=colors[m], label=lab, ms=7)
        ax.axhline(ref_noise[n], color="grey", lw=0.8, ls="--")
        ax.set_title(n, fontsize=9)
        ax.set_xlabel("ms per call (warm)")
        ax.set_ylabel("relative RMS error")
        ax.grid(True, which="both", alpha=0.3)
    for ax in axes.ravel()[len(names):]:
        ax.axis("off")
    handles, leg = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, leg, loc="lower right", fontsize=8, ncol=1, bbox_to_anchor=(0.99, 0.02))
    fig.suptitle(f"relight.render methods: error vs time (head, {P} samples; dashed: reference noise)")
    fig.tight_layout()
    png = args.out.with_suffix(".png")
    save_figure(fig, png, dpi=110)
    print(f"wrote {png} and {md} in {time.perf_counter() - t_start:.0f} s")


if __name__ == "__main__":
    main()

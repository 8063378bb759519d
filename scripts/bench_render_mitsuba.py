"""Model-based relighting against Mitsuba 3 at equal accuracy, in one run on one machine.

    python scripts/bench_render_mitsuba.py                          # grace + royal_esplanade_1k, ~25 min on 2 cores
    python scripts/bench_render_mitsuba.py --envmaps grace --ref-spp 1024 --repeats 1   # a smoke run

Scene: the bundled head (``stage.load_head()``), texel maps on a 256^2 grid,
Lambert rho_d = (0.6, 0.42, 0.33) + GGX alpha 0.3 with Schlick F0 = 0.04, no
subsurface; a 128 x 128 pinhole view from 600 mm (fov 24 deg); a lat-long map,
direct light only. Mitsuba renders the scene ``relight.export.write_mitsuba_scene``
exports with ``fresnel="schlick"`` (the fitted model's Fresnel exactly) and
the environment resampled to relight's piecewise-constant pixels
(``relight.export.mitsuba_envmap``), ``path`` integrator with max_depth 2 (direct light only),
``hide_emitters`` (black background, as ``render_view(background=False)``),
box pixel filter, two variants: ``scalar_rgb`` (renders the reference) and
``llvm_ad_rgb`` (Dr.Jit's vectorised LLVM backend, Mitsuba's fastest on a
CPU; the system's LLVM 14/15 fail to select ``fminimum``, so point
``DRJIT_LIBLLVM_PATH`` at a newer libLLVM, e.g. the 22.1 one a Rust toolchain
ships; the line is left out when the variant does not start). The LLVM
variant renders in passes of at most 256 spp (seeds differ, images averaged:
all samples of one call are one wavefront in memory); its first call, which
compiles the kernels, is listed apart like ours.

Per map: a reference (Mitsuba at ``--ref-spp``; its own noise estimated from a
second render at a quarter of the samples), a cross-check of the reference
against ours at high quality ("lights" with 2048 lights, 3 x 3 supersampling),
then Mitsuba at 4 ... 4096 spp and each of our methods at several settings.

Error: PSNR = 10 log10(peak^2 / MSE) against the reference over the
*interior* pixels (all 4 x 4 sub-pixel primary rays hit the mesh: no
background, no silhouette), RGB, peak = the reference's maximum over those
pixels; also relative RMS there, and PSNR over all pixels (silhouettes
included: anti-aliasing counts). Time: wall-clock seconds of one render call,
median of ``--repeats``; Mitsuba's ``mi.render`` (scene loaded once: its load
time is listed apart), ours ``render_view`` from the maps, mesh and camera
(primary rays, map lookups, light set or grid, visibility rays, shading),
warm: the JIT compilation of the first call is listed apart ("first call").
The texel maps and the mesh are loaded once for both (scene load).
"""

from __future__ import annotations

import datetime
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from _common import cpu_model, parser, save_figure

import relight
import stage
from relight import render
from relight.envmap import load_envmap
from relight.export import write_mitsuba_scene
from relight.io import read_maps, write_maps

ROOT = Path(__file__).resolve().parents[1]
ENVMAPS = ROOT.parent / "shared" / "data" / "envmaps"
RHO_D, F0, ALPHA = (0.6, 0.42, 0.33), 0.04, 0.3
TARGET_DB = 40.0


def scene(texels: int, size: int):
    mesh = stage.load_head()
    surf = stage.texel_samples(mesh, texels)
    maps = relight.material_maps(surf, np.array(RHO_D), F0, ALPHA)
    cam = stage.look_at((0.0, 0.0, 600.0), fov_deg=24, width=size, height=size)
    hit = stage.primary_hits(mesh, cam, 4)[0].reshape(size, 4, size, 4)
    return mesh, surf, maps, cam, hit.all(axis=(1, 3))


def metrics(img, ref, interior):
    x, y = np.asarray(img, np.float64), np.asarray(ref, np.float64)
    xi, yi = x[interior], y[interior]
    peak = yi.max()
    mse = np.mean((xi - yi) ** 2)
    mse_all = np.mean((x - y) ** 2)
    return {"psnr": float(10 * np.log10(peak**2 / max(mse, 1e-30))),
            "rel_rms": float(np.sqrt(mse / np.mean(yi**2))),
            "psnr_all": float(10 * np.log10(peak**2 / max(mse_all, 1e-30)))}


def mitsuba_scene(folder: Path, mesh, surf, maps, cam, env_path: Path):
    import mitsuba as mi

    write_maps(folder / "maps", maps, surf)
    tex, _ = read_maps(folder / "maps")
    xml = write_mitsuba_scene(folder / "scene", mesh, tex, cam, env_path, max_depth=2, fresnel="schlick")
    text = xml.read_text().replace('<integrator type="path">',
                                   '<integrator type="path">\n    <boolean name="hide_emitters" value="true" />')
    xml.write_text(text)
    t = time.perf_counter()
    sc = mi.load_file(str(xml))
    return sc, time.perf_counter() - t


def llvm_scene(folder: Path):
    """(scene, load seconds) of the exported scene in ``llvm_ad_rgb``, or None when the variant does not start."""
    import mitsuba as mi

    try:
        mi.set_variant("llvm_ad_rgb")
        t = time.perf_counter()
        sc = mi.load_file(str(folder / "scene" / "scene.xml"))
        load_s = time.perf_counter() - t
        np.asarray(mi.render(sc, spp=1, seed=0))
        return sc, load_s
    except Exception as e:  # no LLVM, or one Dr.Jit cannot use: leave the line out
        print(f"  llvm_ad_rgb unavailable: {type(e).__name__}: {e}")
        return None
    finally:
        mi.set_variant("scalar_rgb")


def render_llvm(sc, spp: int, seed: int) -> np.ndarray:
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    try:
        per = min(spp, 256)
        n = -(-spp // per)
        acc = None
        for k in range(n):
            img = np.asarray(mi.render(sc, spp=per, seed=seed * 1000 + k), np.float64)
            acc = img if acc is None else acc + img
        return acc / n
    finally:
        mi.set_variant("scalar_rgb")


def timed(fn, repeats):
    times, out = [], None
    for r in range(repeats):
        t = time.perf_counter()
        out = fn(r)
        times.append(time.perf_counter() - t)
    return out, statistics.median(times), times


def ours_settings(quick: bool):
    rows = []
    for ss in (1, 2):
        for k in ((64, 256) if quick else (32, 64, 128, 256, 512, 1024)):
            rows.append((f"lights ss{ss}", f"{k} lights", render.Lights(lights=k), ss))
    for ss in (1, 2):
        for r in ((16,) if quick else (16, 32)):
            rows.append((f"dense ss{ss}", f"{r} x {2 * r}", render.Dense(rows=r), ss))
    rows.append(("fast ss2", "SH2 + split-sum + AO 64", render.Fast(), 2))
    return rows


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("--envmaps", nargs="+", default=["grace", "royal_esplanade_1k"])
    ap.add_argument("--ref-spp", type=int, default=8192)
    ap.add_argument("--spp", type=int, nargs="+", default=[4, 16, 64, 256, 1024, 4096])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--texels", type=int, default=256)
    ap.add_argument("--quick", action="store_true", help="fewer settings of ours")
    ap.add_argument("--no-check", action="store_true", help="skip the high-quality cross-check of the reference")
    ap.add_argument("--no-llvm", action="store_true", help="leave out Mitsuba's llvm_ad_rgb variant")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "figures" / "render_vs_mitsuba")
    ap.add_argument("--cache", type=Path, default=None,
                    help="folder to keep the Mitsuba reference renders in and reuse them from (same scene and spp)")
    args = ap.parse_args(argv)

    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    t0 = time.perf_counter()
    mesh, surf, maps, cam, interior = scene(args.texels, args.size)
    print(f"head: {surf.num_samples} texels, {args.size}^2 view, {int(interior.sum())} interior pixels")
    results = {}   # env -> list of dict rows
    info = {}
    first_call = None
    tmp = Path(tempfile.mkdtemp(prefix="bench_mitsuba_"))
    for name in args.envmaps:
        env_path = ENVMAPS / f"{name}.hdr"
        env = load_envmap(env_path)
        sc, load_s = mitsuba_scene(tmp / name, mesh, surf, maps, cam, env_path)
        cached = None if args.cache is None else args.cache / f"{name}_{args.size}_{args.ref_spp}.npz"
        if cached is not None and cached.is_file():
            z = np.load(cached)
            ref, quarter, ref_s = z["ref"], z["quarter"], float(z["ref_s"])
        else:
            t = time.perf_counter()
            ref = np.asarray(mi.render(sc, spp=args.ref_spp, seed=1000))
            ref_s = time.perf_counter() - t
            quarter = np.asarray(mi.render(sc, spp=max(1, args.ref_spp // 4), seed=2000))
            if cached is not None:
                cached.parent.mkdir(parents=True, exist_ok=True)
                np.savez(cached, ref=ref, quarter=quarter, ref_s=ref_s)
        # A render with 1/4 of the samples has twice the reference's standard error:
        # E|q - ref|^2 = (4 + 1) sigma_ref^2.
        noise_mse = np.mean((quarter[interior].astype(np.float64) - ref[interior]) ** 2) / 5.0
        ref_noise_db = float(10 * np.log10(ref[interior].max() ** 2 / noise_mse))
        rows = []
        info[name] = {"load_s": load_s, "ref_s": ref_s, "ref_noise_db": ref_noise_db, "env": env.radiance.shape}
        print(f"{name}: Mitsuba load {load_s:.2f} s, reference {args.ref_spp} spp {ref_s:.1f} s, "
              f"its noise {ref_noise_db:.1f} dB")
        if not args.no_check:
            t = time.perf_counter()
            hq = render.render_view(maps, surf, mesh, cam, env, method=render.Lights(lights=2048), supersample=3,
                                    background=False)
            m = metrics(hq, ref, interior)
            info[name]["check"] = {**m, "s": time.perf_counter() - t}
            print(f"  cross-check: ours (lights 2048, 3x3) vs Mitsuba {args.ref_spp} spp: {m['psnr']:.1f} dB "
                  f"(interior), rel RMS {m['rel_rms']:.4f}, {m['psnr_all']:.1f} dB all pixels")
        llvm = None if args.no_llvm else llvm_scene(tmp / name)
        if llvm is not None:
            sc_l, info[name]["llvm_load_s"] = llvm
            for spp in args.spp:
                reps = args.repeats if spp <= 1024 else max(1, min(2, args.repeats))
                t = time.perf_counter()
                render_llvm(sc_l, spp, 99)
                first = time.perf_counter() - t
                img, med, ts = timed(lambda r, spp=spp, sc_l=sc_l: render_llvm(sc_l, spp, r + 1), reps)
                m = metrics(img, ref, interior)
                rows.append({"method": "mitsuba llvm", "setting": f"{spp} spp", "s": med, "times": ts,
                             "first_s": first, **m})
                print(f"  mitsuba llvm {spp:5d} spp: {med:7.2f} s (first {first:6.2f} s)  {m['psnr']:5.1f} dB  "
                      f"rel {m['rel_rms']:.4f}")
        for spp in args.spp:
            reps = args.repeats if spp <= 1024 else max(1, min(2, args.repeats))
            img, med, ts = timed(lambda r, spp=spp, sc=sc: np.asarray(mi.render(sc, spp=spp, seed=r + 1)), reps)
            m = metrics(img, ref, interior)
            rows.append({"method": "mitsuba scalar", "setting": f"{spp} spp", "s": med, "times": ts, "first_s": None,
                         **m})
            print(f"  mitsuba scalar {spp:5d} spp: {med:7.2f} s  {m['psnr']:5.1f} dB  rel {m['rel_rms']:.4f}")
        for line, label, method, ss in ours_settings(args.quick):
            def call(r, method=method, ss=ss, env=env):
                return render.render_view(maps, surf, mesh, cam, env, method=method, supersample=ss, background=False)
            t = time.perf_counter()
            call(0)
            first = time.perf_counter() - t
            if first_call is None:
                first_call = (f"{line}: {label}", first)
            img, med, ts = timed(call, args.repeats)
            m = metrics(img, ref, interior)
            rows.append({"method": line, "setting": label, "s": med, "times": ts, "first_s": first, **m})
            print(f"  {line:10s} {label:24s}: {med:7.2f} s (first call {first:6.2f} s)  {m['psnr']:5.1f} dB  "
                  f"rel {m['rel_rms']:.4f}")
        results[name] = rows
        print(f"  elapsed {time.perf_counter() - t0:.0f} s")
    write_outputs(args, results, info, first_call, int(interior.sum()))
    print(f"done in {time.perf_counter() - t0:.0f} s")


def time_to_target(rows, method):
    ok = [r["s"] for r in rows if r["method"] == method and r["psnr"] >= TARGET_DB]
    return min(ok) if ok else None


def write_outputs(args, results, info, first_call, n_interior):
    names = list(results)
    methods = list(dict.fromkeys(r["method"] for r in results[names[0]]))
    cpu = cpu_model()
    import os

    lines = [f"<!-- generated by scripts/bench_render_mitsuba.py --envmaps {' '.join(names)} --ref-spp {args.ref_spp} "
             f"--repeats {args.repeats} -->", "",
             f"Machine: {cpu}, {os.cpu_count()} cores shared with other jobs (timings noisy, median of "
             f"{args.repeats} runs; 4096-spp Mitsuba of {min(2, args.repeats)}), no GPU. "
             f"Date: {datetime.date.today().isoformat()}. Mitsuba {__import__('mitsuba').__version__} (scalar_rgb; "
             f"llvm_ad_rgb with DRJIT_LIBLLVM_PATH={os.environ.get('DRJIT_LIBLLVM_PATH', '-')}).",
             "",
             f"Scene: head, {args.size}^2 pixels, Lambert (0.6, 0.42, 0.33) + GGX alpha {ALPHA} Schlick F0 {F0}, "
             "direct light only. PSNR over the "
             f"{n_interior} interior pixels (all 4x4 sub-pixel rays hit the head), RGB, peak = the reference's "
             "maximum there; 'PSNR all' over every pixel (black background, silhouettes included). Reference: "
             f"Mitsuba at {args.ref_spp} spp. Time: one render call (s), median; Mitsuba's scene load and our "
             "first call's JIT compilation excluded (listed apart).", ""]
    for n in names:
        i = info[n]
        llvm_load = f" (llvm_ad_rgb {i['llvm_load_s']:.2f} s)" if "llvm_load_s" in i else ""
        lines.append(f"* **{n}** ({i['env'][0]} x {i['env'][1]}): Mitsuba scene load {i['load_s']:.2f} s"
                     f"{llvm_load}, "
                     f"reference {i['ref_s']:.0f} s, its noise {i['ref_noise_db']:.1f} dB"
                     + (f"; ours at high quality (lights 2048, 3x3 supersampling, {i['check']['s']:.0f} s) vs the "
                        f"reference: {i['check']['psnr']:.1f} dB interior (rel RMS {i['check']['rel_rms']:.4f}), "
                        f"{i['check']['psnr_all']:.1f} dB all pixels" if "check" in i else ""))
    if first_call:
        lines.append(f"* first call of ours in the process ({first_call[0]}): {first_call[1]:.1f} s "
                     "(JIT compilation of the kernels + the render); later first calls of a setting are listed "
                     "per row.")
    lines.append("")
    lines.append(f"Time to reach {TARGET_DB:.0f} dB (fastest measured setting at or above it, s):")
    lines.append("")
    lines.append("| method | " + " | ".join(names) + " |")
    lines.append("| --- | " + " | ".join("---" for _ in names) + " |")
    for m in methods:
        vals = [time_to_target(results[n], m) for n in names]
        lines.append(f"| {m} | " + " | ".join("not reached" if v is None else f"{v:.2f}" for v in vals) + " |")
    lines.append("")
    hdr = "| method | setting | " + " | ".join(f"{n}: s / dB / rel RMS / dB all" for n in names) + " | first call (s) |"
    lines += [hdr, "| --- | --- | " + " | ".join("---" for _ in names) + " | --- |"]
    for k, r0 in enumerate(results[names[0]]):
        cells = []
        for n in names:
            r = results[n][k]
            cells.append(f"{r['s']:.2f} / {r['psnr']:.1f} / {r['rel_rms']:.4f} / {r['psnr_all']:.1f}")
        first = "-" if r0["first_s"] is None else " / ".join(f"{results[n][k]['first_s']:.2f}" for n in names)
        lines.append(f"| {r0['method']} | {r0['setting']} | " + " | ".join(cells) + f" | {first} |")
    table = "\n".join(lines)
    print(table)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    md = args.out.with_suffix(".md")
    tmp = md.with_name(md.name + ".tmp")
    tmp.write_text(table + "\n")
    tmp.replace(md)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(names), figsize=(6.2 * len(names), 4.6), squeeze=False)
    style = {"mitsuba scalar": ("k", "o", "-"), "mitsuba llvm": ("dimgrey", "o", "--"),
             "lights ss1": ("tab:orange", "s", "-"), "lights ss2": ("tab:red", "s", "-"),
             "dense ss1": ("tab:blue", "^", "--"), "dense ss2": ("tab:purple", "^", "--"),
             "fast ss2": ("tab:green", "D", ":")}
    for ax, n in zip(axes[0], names, strict=False):
        for m in methods:
            pts = [r for r in results[n] if r["method"] == m]
            c, mk, ls = style.get(m, ("grey", "x", "-"))
            ax.semilogx([r["s"] for r in pts], [r["psnr"] for r in pts], color=c, marker=mk, ls=ls,
                        label=f"Mitsuba 3 {m.split()[1]} (spp)" if m.startswith("mitsuba") else m)
            if m.startswith("mitsuba"):
                for r in pts:
                    ax.annotate(r["setting"].split()[0], (r["s"], r["psnr"]), fontsize=7, xytext=(3, -9),
                                textcoords="offset points")
        ax.axhline(TARGET_DB, color="grey", lw=0.8)
        ax.axhline(info[n]["ref_noise_db"], color="grey", lw=0.8, ls="--")
        ax.set_title(f"{n} (dashed: reference noise)", fontsize=9)
        ax.set_xlabel("seconds per 128^2 render (warm, median)")
        ax.set_ylabel("PSNR vs Mitsuba reference, interior pixels (dB)")
        ax.grid(True, which="both", alpha=0.3)
    axes[0, 0].legend(fontsize=8, loc="lower right")
    fig.suptitle("relight.render vs Mitsuba 3: error vs time (head, direct light, same machine, same run)")
    fig.tight_layout()
    png = args.out.with_suffix(".png")
    save_figure(fig, png, dpi=110)
    print(f"wrote {png} and {md}")


if __name__ == "__main__":
    main()

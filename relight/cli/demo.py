"""The main job end to end on built-in data, on the real problem: the bundled
head scan with its own skin textures (albedo, specular and normal maps) and
spatially varying subsurface scattering, photographed under the bundled Light
Stage X by several cameras with sensor noise; the full model ladder fitted
(BRDF rungs, then none / per-region / per-texel subsurface); the fitted maps
and the truth maps relit by the same renderer under the bundled environment
map; a report of every map's error over the seen texels and the time of each
stage."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ._common import (
    INDEX_FRAMES,
    INDEX_SIZE,
    CLIError,
    add_envmap,
    add_image_size,
    add_index_flag,
    add_out,
    at_least,
    bar,
    finish_parser,
    front_ring,
    summary,
    write_index_page,
)

# Shot noise: this many photo-electrons at the median observed radiance (1% relative noise there).
_ELECTRONS_AT_MEDIAN = 1.0e4


def add_parser(sub) -> None:
    d = sub.add_parser("demo", help="simulate, fit and relight the bundled textured head (built-in defaults)",
                       description="Run the whole pipeline on built-in data: the bundled head scan with its skin "
                                   "textures and subsurface scattering, simulated under the bundled Light Stage X "
                                   "by --cameras cameras with shot noise (--noise), the full model ladder fitted "
                                   "(BRDF rungs, then none / per-region / per-texel subsurface), fit and truth "
                                   "relit under --envmap; writes OUT/maps/, OUT/truth/, relit EXRs, preview.png, "
                                   "report.md/report.json (every map's error over the seen texels) and "
                                   "settings.json. Takes minutes at the defaults; --resolution 32 --cameras 2 for "
                                   "a quick look.")
    add_out(d, "output folder (default: ./relight-demo)", default="relight-demo")
    d.add_argument("--resolution", type=int, default=96, help="texel grid size (default: 96)")
    d.add_argument("--cameras", type=int, default=3, help="cameras over 80 degrees around the front (default: 3)")
    d.add_argument("--noise", type=float, default=0.01,
                   help="relative shot noise at the median observed radiance (default: 0.01; 0 = noise-free)")
    d.add_argument("--seed", type=int, default=0, help="noise seed (default: 0)")
    d.add_argument("--passes", type=int, default=2,
                   help="BRDF / subsurface alternations (relight.fit_with_subsurface; default: 2)")
    add_envmap(d)
    add_image_size(d, 320, "preview image size in pixels")
    add_index_flag(d)
    finish_parser(d, run)


def run(args) -> int:
    from ..envmap import load_envmap

    at_least("--resolution", args.resolution, 16)
    at_least("--cameras", args.cameras, 1)
    at_least("--image-size", args.image_size, 16)
    at_least("--passes", args.passes, 1)
    if not 0 <= args.noise < 1:
        raise CLIError(f"--noise {args.noise}: must be in [0, 1)")
    if args.envmap is not None:
        load_envmap(args.envmap)  # refuse a missing or corrupt map before minutes of simulation and fitting
    report = run_demo(Path(args.out), resolution=args.resolution, envmap=args.envmap, image_size=args.image_size,
                      cameras=args.cameras, noise=args.noise, seed=args.seed, passes=args.passes, quiet=args.quiet,
                      index=not args.no_index)
    if not summary(args):
        return 0
    e = report["errors"]
    print(f"wrote {args.out}/ (report.md, report.json, preview.png, maps/, truth/)")
    m = e["mfp_rel_identified"]["median"]
    mfp = "n/a" if m is None else f"{100 * m:.1f}%"
    print(f"over {report['texels_seen']} seen texels, median: diffuse albedo "
          f"{100 * e['diffuse_albedo_rel']['median']:.2f}%, "
          f"mean free path {mfp} ({100 * report['mfp_identified_fraction']:.0f}% of texel-channels identified), "
          f"relit PSNR vs truth {report['relit_psnr_db']:.1f} dB")
    return 0


def _simulate(surface, truth, rig, cams, light_vis, cam_vis, noise: float, seed: int, quiet: int | bool):
    """The OLAT capture of the truth maps: the GGX lobe in the normal-mapped
    frame plus Jensen 2001 eq. 5 through the diffusion operator, then the sensor."""
    import jax
    import jax.numpy as jnp

    import skin_bssrdf
    import stage

    widest = skin_bssrdf.Burley(jnp.full((3,), 0.8), jnp.asarray(np.max(np.asarray(truth.mfp), 0) / 2.0))
    radius = float(np.max(np.asarray(skin_bssrdf.energy_radius(widest, 0.99))))
    op = skin_bssrdf.DiffusionOperator.build(np.asarray(surface.position), np.asarray(surface.area), radius)
    sss = stage.Subsurface(truth.profile(), op, 1.4)
    with bar(len(cams) * rig.num_lights, "simulate (images)", quiet, leave=True) as b:
        capture = stage.simulate(truth.frame(surface), rig, cams, truth.brdf(), light_vis, cam_vis, progress=b,
                                 subsurface=sss)
    if noise > 0:
        lit = np.asarray(capture.radiance)[np.asarray(capture.mask)]
        median = float(np.median(lit[lit > 0]))
        exposure = 1.0 / (noise * noise * median)  # Poisson: sigma / mean = 1 / sqrt(exposure x radiance)
        capture = stage.sense(capture, stage.Sensor(exposure=exposure, shot_noise=True), jax.random.PRNGKey(seed))
    return capture, radius


def _angle_deg(a, b) -> np.ndarray:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    c = np.sum(a * b, 1) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-30)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def _stats(x) -> dict:
    x = np.asarray(x, np.float64)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return {"median": None, "p95": None, "samples": 0}  # JSON has no NaN
    return {"median": float(np.median(x)), "p95": float(np.percentile(x, 95)), "samples": int(x.size)}


def _errors(fitted, truth) -> dict:
    """Per-map errors of the fit against the truth over every seen texel (the
    demo's samples), flagged or not; roughness over texels with a lobe, mean
    free path over texels where the fit says it is identified."""
    from ..materials import BLINN_PHONG, SUBSURFACE

    rel = lambda est, ref: np.abs(np.asarray(est, np.float64) - np.asarray(ref, np.float64)) / np.asarray(  # noqa: E731
        ref, np.float64)
    model = np.asarray(fitted.model)
    lobe = model >= BLINN_PHONG
    mfp_t = np.asarray(truth.mfp, np.float64)
    mfp_f = np.asarray(fitted.mfp, np.float64) if fitted.mfp is not None else np.zeros_like(mfp_t)
    ident = getattr(fitted, "mfp_identified", None)
    ident = np.zeros_like(mfp_t, bool) if ident is None else np.asarray(ident, bool)
    e_mfp = rel(mfp_f, mfp_t)
    out = {
        "diffuse_albedo_rel": _stats(rel(fitted.rho_d, truth.rho_d).mean(1)),
        "specular_albedo_rel": _stats(rel(fitted.rho_s, truth.rho_s)[:, 0]),
        "roughness_rel_lobe_texels": _stats(rel(fitted.alpha[:, :1], truth.alpha[:, :1])[lobe, 0]),
        "normal_deg": _stats(_angle_deg(fitted.normal, truth.normal)),
        "mfp_rel_all": _stats(e_mfp.reshape(-1)),
        "mfp_rel_identified": _stats(e_mfp[ident]),
    }
    for c, name in enumerate("rgb"):
        out[f"mfp_rel_identified_{name}"] = _stats(e_mfp[ident[:, c], c])
    out["subsurface_texels"] = int(np.sum(model == SUBSURFACE))
    # The names `relight fit`'s report uses (diffuse / specular albedo); the demo's old keys stay one more
    # version, as copies, for scripts that read them.
    for old, new in DEPRECATED_KEYS.items():
        out[old] = out[new]
    return out


# Old report.json error keys of the demo -> the names shared with `relight fit` (deprecated; still written).
DEPRECATED_KEYS = {"albedo_rel": "diffuse_albedo_rel", "specular_rel": "specular_albedo_rel"}


def _psnr(est: np.ndarray, ref: np.ndarray, covered: np.ndarray) -> float:
    """PSNR (dB) over the covered pixels, peak = the reference's maximum there."""
    d = (est - ref)[covered]
    mse = float(np.mean(d * d)) if d.size else 0.0
    peak = float(np.max(ref[covered])) if d.size else 1.0
    return float(10 * np.log10(peak * peak / max(mse, 1e-30)))


def run_demo(out: Path, resolution: int = 96, envmap: Path | None = None, image_size: int = 320, cameras: int = 3,
             noise: float = 0.01, seed: int = 0, passes: int = 2, quiet: int | bool = 0, index: bool = True) -> dict:
    """Run the whole demo into ``out``; returns the report as a dict. ``index``: also write index.html (the
    results viewer, with the capture relit image-based under a rotation sweep)."""
    import stage

    from ..envmap import load_envmap
    from ..fitting import fit_with_subsurface
    from ..io import head_skin_textures, texture_set, write_texture_set
    from ..materials import MODELS, skin_maps
    from ..render import render_view
    from ..results import atomic_write_text

    out = Path(out)
    from ._common import check_out, envmap_path, output_set

    check_out(out, "demo")  # refused before the work; output_set checks again, locked, before writing

    envmap = envmap_path(None if envmap is None else str(envmap))
    times = {}
    t0 = time.perf_counter()
    mesh = stage.load_head()
    full = stage.texel_samples(mesh, resolution)
    rig = stage.light_stage_x()
    cams = front_ring(mesh, cameras, image_size)
    times["geometry"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    with bar(full.num_samples * rig.num_lights, "visibility (rays)", quiet, leave=True) as b:
        light_vis = stage.light_visibility(mesh, full, rig, chunk=1 << 18, progress=b)
    cam_vis = stage.camera_visibility(mesh, full, cams)
    seen = np.flatnonzero(cam_vis.any(axis=0))
    surface, light_vis, cam_vis = full.subset(seen), np.asarray(light_vis)[seen], cam_vis[:, seen]
    times["visibility"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    skin = skin_maps(surface, head_skin_textures())
    truth = skin.maps(surface)
    capture, radius = _simulate(surface, truth, rig, cams, light_vis, cam_vis, noise, seed, quiet)
    times["simulate"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    with bar(surface.num_samples, "fit (texels)", quiet, leave=True) as b:
        fitted = fit_with_subsurface(capture, surface, model="auto", normals=True, per="auto", passes=passes,
                                     regions=skin.regions, radius_mm=radius, progress=b)
    times["fit"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    env = load_envmap(envmap)
    maps = fitted.maps(surface)
    view_cam = cams[len(cams) // 2]
    relit_truth = render_view(truth, surface, mesh, view_cam, env, method="rig", rig=rig, background=False)
    relit_fit = render_view(maps, surface, mesh, view_cam, env, method="rig", rig=rig, background=False)
    times["relight"] = time.perf_counter() - t0
    covered = np.asarray(stage.primary_hits(mesh, view_cam, 1)[0])

    model = np.asarray(fitted.model)
    rung = getattr(fitted, "mfp_rung", None)
    ident = getattr(fitted, "mfp_identified", None)
    report = {
        "texels_seen": int(surface.num_samples),
        "texels_on_atlas": int(full.num_samples),
        "lights": int(rig.num_lights),
        "cameras": len(cams),
        "texel_resolution": int(resolution),
        "noise_relative_at_median": float(noise),
        "envmap": str(envmap),
        "errors": _errors(fitted, truth),
        "deprecated_error_keys": DEPRECATED_KEYS,  # copies kept for old readers: old name -> current name
        "model_fraction": {MODELS[m]: float(np.mean(model == m)) for m in range(len(MODELS))},
        "subsurface_rung_fraction": (None if rung is None else
                                     {k: float(np.mean(np.asarray(rung) == i))
                                      for i, k in enumerate(("none", "region", "texel"))}),
        "mfp_identified_fraction": 0.0 if ident is None else float(np.mean(np.asarray(ident))),
        "flagged_fraction": float(np.mean(np.asarray(fitted.failed))),
        "relit_psnr_db": _psnr(relit_fit, relit_truth, covered),
        "relit_pixels": int(covered.sum()),
        "operator_radius_mm": radius,
        "timings_s": {k: round(v, 2) for k, v in times.items()},
    }
    settings = {"command": "relight demo", "out": str(out), "resolution": resolution, "envmap": str(envmap),
                "image_size": image_size, "cameras": len(cams), "noise": noise, "seed": seed, "passes": passes,
                "rig": "light_stage_x", "textures": "Lee Perry-Smith head scan (Infinite Realities, CC-BY 3.0)",
                "camera": stage.camera_to_dict(view_cam, "relit")}  # the relit images' camera (relight view's)
    # The whole demo folder is one result set: built beside out, swapped in with its manifest.
    with output_set(out, "demo", quiet) as tmp:
        t0 = time.perf_counter()
        _write(tmp, mesh, surface, truth, maps, view_cam, relit_truth, relit_fit, covered, report,
               texture_set, write_texture_set)
        report["timings_s"]["write"] = round(time.perf_counter() - t0, 2)
        atomic_write_text(tmp / "settings.json", json.dumps(settings, indent=2))
        atomic_write_text(tmp / "report.json", json.dumps(report, indent=2, allow_nan=False))
        atomic_write_text(tmp / "report.md", _report_md(report))
        if index:
            write_index_page(tmp, lambda: _index_sweeps(capture, surface, mesh, view_cam, env), "demo",
                             quiet, location=out)
    return report


def _write(out, mesh, surface, truth, maps, camera, relit_truth, relit_fit, covered, report, texture_set,
           write_texture_set):
    """Texture sets (fit and truth), relit EXRs and the preview, columns truth |
    fit | error: relit (error: |fit - truth| / the 90th-percentile pixel, 0-10%),
    diffuse albedo (relative error 0-10%), red mean free path (0 to the truth's
    maximum; relative error 0-50%)."""
    import stage

    from ..image._exposure import subject_exposure
    from ..image._preview import dilate, texture_view
    from ..image._tonemap import to_uint8, tonemap
    from ..io import mesh_spec, write_exr, write_png

    # The bundled head's spec and the relit camera, so that `relight view` (and `relight render`) can rebuild
    # the texel surface and render the sets as the demo did.
    info = mesh_spec(None, units=None, scale=None, center=None)
    meta = {"source": "relight demo", "cameras": [stage.camera_to_dict(camera, "relit")], "rig": None}
    write_texture_set(out / "maps", texture_set(maps, surface, surface_info=info, metadata=meta))
    write_texture_set(out / "truth", texture_set(truth, surface, surface_info=info, metadata=meta))
    write_exr(out / "relit_truth.exr", relit_truth)
    write_exr(out / "relit_fit.exr", relit_fit)
    # Exposure from the subject: its median pixel to 0.35 before the filmic curve (sun glints would
    # set a 99th percentile and darken the face).
    exposure = subject_exposure(relit_truth, covered)  # the one rule every render's preview uses
    tm = lambda img: to_uint8(tonemap(img, exposure=exposure, curve="filmic"))  # noqa: E731

    def heat(x, vmax, where):
        import matplotlib

        rgb = matplotlib.colormaps["magma"](np.clip(x / vmax, 0.0, 1.0))[..., :3]
        return to_uint8(np.where(where[..., None], rgb, 0.0).astype(np.float32))

    err_relit = np.abs(relit_fit - relit_truth).mean(-1) / max(float(np.percentile(relit_truth[covered], 90)), 1e-6)
    rows = [[tm(relit_truth), tm(relit_fit), heat(err_relit, 0.1, covered)]]
    valid = np.zeros(surface.resolution, bool)
    valid.reshape(-1)[np.asarray(surface.texel_index)] = True
    tex = lambda x: dilate(surface.to_texture(np.asarray(x, np.float32)), valid)  # noqa: E731
    rho_t, rho_f = np.asarray(truth.rho_d, np.float32), np.asarray(maps.rho_d, np.float32)
    mfp_t, mfp_f = np.asarray(truth.mfp, np.float32)[:, :1], np.asarray(maps.mfp, np.float32)[:, :1]
    views = texture_view(mesh, camera, {
        "on": tex(np.ones_like(mfp_t)), "albedo_t": tex(rho_t), "albedo_f": tex(rho_f),
        "albedo_e": tex(np.abs(rho_f - rho_t).mean(1, keepdims=True) / np.maximum(rho_t.mean(1, keepdims=True), 1e-6)),
        "mfp_t": tex(mfp_t), "mfp_f": tex(mfp_f), "mfp_e": tex(np.abs(mfp_f - mfp_t) / np.maximum(mfp_t, 1e-6)),
    })
    on = views["on"][..., 0] > 0.5
    srgb = lambda img: to_uint8(tonemap(np.clip(img, 0, 1), curve="none"))  # noqa: E731
    vmax = float(np.max(mfp_t))
    rows.append([srgb(views["albedo_t"]), srgb(views["albedo_f"]), heat(views["albedo_e"][..., 0], 0.1, on)])
    rows.append([heat(views["mfp_t"][..., 0], vmax, on), heat(views["mfp_f"][..., 0], vmax, on),
                 heat(views["mfp_e"][..., 0], 0.5, on)])
    write_png(out / "preview.png", np.concatenate([np.concatenate(r, axis=1) for r in rows], axis=0))


def _fmt(s: dict, pct: bool = True) -> str:
    if not s["samples"]:
        return "n/a | n/a | 0"
    f = (lambda x: f"{100 * x:.2f}%") if pct else (lambda x: f"{x:.2f}")
    return f"{f(s['median'])} | {f(s['p95'])} | {s['samples']}"


def _report_md(r: dict) -> str:
    e = r["errors"]
    t = r["timings_s"]
    rungs = r["subsurface_rung_fraction"]
    lines = [
        "# relight demo report", "",
        f"The bundled head scan with its own skin textures (Lee Perry-Smith, Infinite Realities, CC-BY 3.0) and "
        f"spatially varying subsurface scattering, {r['lights']} lights (ICT Light Stage X), {r['cameras']} cameras, "
        f"texel grid {r['texel_resolution']}^2 ({r['texels_seen']} of {r['texels_on_atlas']} atlas texels seen by "
        f">= 1 camera), shot noise {100 * r['noise_relative_at_median']:.1f}% at the median radiance, "
        f"environment `{Path(r['envmap']).name}`.", "",
        "Errors of the fit against the truth maps, over every seen texel (flagged ones included) unless the row "
        "says otherwise; `samples` counts texels (texel-channels for the mean free path).", "",
        "| map | median | 95th percentile | samples |", "| --- | --- | --- | --- |",
        f"| diffuse albedo, relative (mean over RGB) | {_fmt(e['diffuse_albedo_rel'])} |",
        f"| specular albedo (Schlick F0), relative | {_fmt(e['specular_albedo_rel'])} |",
        f"| roughness, relative (texels with a specular lobe) | {_fmt(e['roughness_rel_lobe_texels'])} |",
        f"| shading normal, degrees | {_fmt(e['normal_deg'], pct=False)} |",
        f"| mean free path, relative (all texel-channels) | {_fmt(e['mfp_rel_all'])} |",
        f"| mean free path, relative (identified texel-channels) | {_fmt(e['mfp_rel_identified'])} |",
        *[f"| mean free path {c.upper()}, relative (identified) | {_fmt(e[f'mfp_rel_identified_{c}'])} |"
          for c in "rgb"],
        "",
        "Model map: " + ", ".join(f"{k} {100 * v:.1f}%" for k, v in r["model_fraction"].items()) + ".",
    ]
    if rungs is not None:
        lines.append("Subsurface rungs: " + ", ".join(f"{k} {100 * v:.1f}%" for k, v in rungs.items())
                     + f"; mean free path identified on {100 * r['mfp_identified_fraction']:.1f}% of texel-channels.")
    lines += [
        f"Flagged texels: {100 * r['flagged_fraction']:.2f}%.",
        f"Relit (fitted maps vs truth maps, same renderer, same map, view of the middle camera, "
        f"{r['relit_pixels']} head pixels): PSNR {r['relit_psnr_db']:.1f} dB.", "",
        "| stage | seconds |", "| --- | --- |", *[f"| {k} | {v:.1f} |" for k, v in t.items()], "",
    ]
    return "\n".join(lines)


def _index_sweeps(capture, surface, mesh, camera, env):
    """index.html's slider: the simulated capture relit image-based (what the light stage measured, subsurface
    scattering and noise included; memory speed). `relight view OUT` adds the truth and fitted maps rendered
    model-based, which would cost the demo a second renderer compile."""
    from ..view import capture_sweep

    return [capture_sweep(capture, surface, mesh, camera, env, INDEX_FRAMES, INDEX_SIZE,
                          "the simulated capture relit image-based (`relight view` adds truth and fit, "
                          "model-based)")], None

"""The main job end to end on built-in data, on the real problem: the bundled
head scan with its own skin textures (albedo, specular and normal maps) and
spatially varying subsurface scattering, photographed under the bundled Light
Stage X by several cameras with sensor noise; the full model ladder fitted
(BRDF rungs, then none / per-region / per-texel subsurface); the fitted maps
and the truth maps relit by the same renderer under the bundled environment
map; the fit's report against the truth (``relight.fitting.fit_report``: every
map's error over the seen texels) and the time of each stage."""

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
    check_out,
    envmap_path,
    finish_parser,
    front_ring,
    output_set,
    summary,
    write_index_page,
)


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
    e = report["against_truth"]["errors"]
    print(f"wrote {args.out}/ (report.md, report.json, preview.png, maps/, truth/)")
    m = e["mfp_rel_identified"]["all_seen"]["median"]
    mfp = "n/a" if m is None else f"{100 * m:.1f}%"
    print(f"over {report['texels_seen']} seen texels, median: diffuse albedo "
          f"{100 * e['diffuse_albedo_rel']['all_seen']['median']:.2f}%, "
          f"mean free path {mfp} ({100 * report['mfp_identified_fraction']:.0f}% of texel-channels identified), "
          f"relit PSNR vs truth {report['relit_psnr_db']:.1f} dB")
    return 0


def _simulate(surface, truth, rig, cams, light_vis, cam_vis, noise: float, seed: int, quiet: int | bool):
    """The OLAT capture of the truth maps: the GGX lobe in the normal-mapped frame plus Jensen 2001 eq. 5
    through the diffusion operator (its radius: ``skin_bssrdf.operator_radius`` of the truth's profile over
    the scattering texels), then the sensor. Returns (capture, radius in mm)."""
    import jax

    import skin_bssrdf
    import stage

    from ..materials import SUBSURFACE

    profile = truth.profile()
    radius = skin_bssrdf.operator_radius(profile, where=np.asarray(truth.model) == SUBSURFACE)
    op = skin_bssrdf.DiffusionOperator.build(np.asarray(surface.position), np.asarray(surface.area), radius)
    sss = stage.Subsurface(profile, op, skin_bssrdf.SKIN_ETA)
    with bar(len(cams) * rig.num_lights, "simulate (images)", quiet, leave=True) as b:
        capture = stage.simulate(truth.frame(surface), rig, cams, truth.brdf(), light_vis, cam_vis, progress=b,
                                 subsurface=sss)
    if noise > 0:
        lit = np.asarray(capture.radiance)[np.asarray(capture.mask)]
        median = float(np.median(lit[lit > 0]))
        exposure = 1.0 / (noise * noise * median)  # Poisson: sigma / mean = 1 / sqrt(exposure x radiance)
        capture = stage.sense(capture, stage.Sensor(exposure=exposure, shot_noise=True), jax.random.PRNGKey(seed))
    return capture, radius


def run_demo(out: Path, resolution: int = 96, envmap: Path | None = None, image_size: int = 320, cameras: int = 3,
             noise: float = 0.01, seed: int = 0, passes: int = 2, quiet: int | bool = 0, index: bool = True) -> dict:
    """Run the whole demo into ``out``; returns the report as a dict. ``index``: also write index.html (the
    results viewer, with the capture relit image-based under a rotation sweep)."""
    import stage

    from ..envmap import load_envmap
    from ..fitting import FitOptions, fit_report, fit_with_subsurface
    from ..image import psnr
    from ..io import head_skin_textures
    from ..materials import MODELS, skin_maps
    from ..render import render_view
    from ..results import atomic_write_text

    out = check_out(out, "demo")  # refused before the work; output_set checks again, locked, before writing
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
                                     regions=skin.regions, radius_mm=radius, options=FitOptions(progress=b))
    times["fit"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    env = load_envmap(envmap)
    maps = fitted.maps(surface)
    view_cam = cams[len(cams) // 2]
    relit_truth = render_view(truth, surface, mesh, view_cam, env, method="rig", rig=rig, background=False)
    relit_fit = render_view(maps, surface, mesh, view_cam, env, method="rig", rig=rig, background=False)
    times["relight"] = time.perf_counter() - t0
    covered = np.asarray(stage.primary_hits(mesh, view_cam, 1)[0])

    model, rung, ident = np.asarray(fitted.model), fitted.mfp_rung, fitted.mfp_identified
    report = fit_report(fitted, surface, truth, normals=True, timings={k: round(v, 2) for k, v in times.items()})
    report.update({
        "texels_seen": int(surface.num_samples), "texels_on_atlas": int(full.num_samples),
        "lights": int(rig.num_lights), "cameras": len(cams), "texel_resolution": int(resolution),
        "noise_relative_at_median": float(noise), "envmap": str(envmap),
        "model_fraction": {MODELS[m]: float(np.mean(model == m)) for m in range(len(MODELS))},
        "subsurface_rung_fraction": (None if rung is None else {k: float(np.mean(np.asarray(rung) == i))
                                                                for i, k in enumerate(("none", "region", "texel"))}),
        "mfp_identified_fraction": 0.0 if ident is None else float(np.mean(np.asarray(ident))),
        "flagged_fraction": float(np.mean(np.asarray(fitted.failed))),
        "relit_psnr_db": psnr(relit_fit, relit_truth, covered), "relit_pixels": int(covered.sum()),
        "operator_radius_mm": radius})
    settings = {"command": "relight demo", "out": str(out), "resolution": resolution, "envmap": str(envmap),
                "image_size": image_size, "cameras": len(cams), "noise": noise, "seed": seed, "passes": passes,
                "rig": "light_stage_x", "textures": "Lee Perry-Smith head scan (Infinite Realities, CC-BY 3.0)",
                "camera": stage.camera_to_dict(view_cam, "relit")}  # the relit images' camera (relight view's)
    # The whole demo folder is one result set: built beside out, swapped in with its manifest.
    with output_set(out, "demo", quiet) as tmp:
        t0 = time.perf_counter()
        _write(tmp, mesh, surface, truth, maps, view_cam, relit_truth, relit_fit, covered)
        report["timings_s"]["write"] = round(time.perf_counter() - t0, 2)
        atomic_write_text(tmp / "settings.json", json.dumps(settings, indent=2))
        _write_report(tmp, report)
        if index:
            write_index_page(tmp, lambda: _index_sweeps(capture, surface, mesh, view_cam, env), "demo",
                             quiet, location=out)
    return report


def _write(out, mesh, surface, truth, maps, camera, relit_truth, relit_fit, covered):
    """Texture sets (fit and truth), relit EXRs and preview.png (``relight.image.truth_fit_figure``)."""
    import stage

    from ..image import truth_fit_figure
    from ..io import mesh_spec, texture_set, write_exr, write_png, write_texture_set

    # The bundled head's spec and the relit camera, so that `relight view` (and `relight render`) can rebuild
    # the texel surface and render the sets as the demo did.
    info = mesh_spec(None, units=None, scale=None, center=None)
    meta = {"source": "relight demo", "cameras": [stage.camera_to_dict(camera, "relit")], "rig": None}
    write_texture_set(out / "maps", texture_set(maps, surface, surface_info=info, metadata=meta))
    write_texture_set(out / "truth", texture_set(truth, surface, surface_info=info, metadata=meta))
    write_exr(out / "relit_truth.exr", relit_truth)
    write_exr(out / "relit_fit.exr", relit_fit)
    write_png(out / "preview.png", truth_fit_figure(mesh, surface, camera, truth, maps, relit_truth, relit_fit,
                                                    covered))


def _write_report(out: Path, r: dict) -> None:
    """report.json and report.md: ``relight.fitting.write_report`` with the demo's description first."""
    from ..fitting import write_report

    rungs = r["subsurface_rung_fraction"]
    preface = [
        f"The bundled head scan with its own skin textures (Lee Perry-Smith, Infinite Realities, CC-BY 3.0) and "
        f"spatially varying subsurface scattering, {r['lights']} lights (ICT Light Stage X), {r['cameras']} cameras, "
        f"texel grid {r['texel_resolution']}^2 ({r['texels_seen']} of {r['texels_on_atlas']} atlas texels seen by "
        f">= 1 camera), shot noise {100 * r['noise_relative_at_median']:.1f}% at the median radiance, "
        f"environment `{Path(r['envmap']).name}`.", "",
        "Model map: " + ", ".join(f"{k} {100 * v:.1f}%" for k, v in r["model_fraction"].items()) + "."]
    if rungs is not None:
        preface.append("Subsurface rungs: " + ", ".join(f"{k} {100 * v:.1f}%" for k, v in rungs.items())
                       + f"; mean free path identified on {100 * r['mfp_identified_fraction']:.1f}% of "
                         "texel-channels.")
    preface += [f"Flagged texels: {100 * r['flagged_fraction']:.2f}%.",
                f"Relit (fitted maps vs truth maps, same renderer, same map, view of the middle camera, "
                f"{r['relit_pixels']} head pixels): PSNR {r['relit_psnr_db']:.1f} dB.", ""]
    write_report(out, r, "relight demo report", preface)


def _index_sweeps(capture, surface, mesh, camera, env):
    """index.html's slider: the simulated capture relit image-based (what the light stage measured, subsurface
    scattering and noise included; memory speed). `relight view OUT` adds the truth and fitted maps rendered
    model-based, which would cost the demo a second renderer compile."""
    from ..view import capture_sweep

    return [capture_sweep(capture, surface, mesh, camera, env, INDEX_FRAMES, INDEX_SIZE,
                          "the simulated capture relit image-based (`relight view` adds truth and fit, "
                          "model-based)")], None

"""The main job end to end on built-in data: simulate the bundled head scan
under the bundled Light Stage X rig, fit its reflectance, relight it under the
bundled environment map, and write EXRs, PNG previews and a report."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ._common import add_envmap, add_image_size, add_out, bar, demo_material, envmap_path, finish_parser


def add_parser(sub) -> None:
    d = sub.add_parser("demo", help="simulate, fit and relight the bundled head scan (built-in defaults)")
    add_out(d, "output folder (default: ./relight-demo)", default="relight-demo")
    d.add_argument("--resolution", type=int, default=128, help="texel grid size (default: 128)")
    add_envmap(d)
    add_image_size(d, 384, "preview image size in pixels")
    finish_parser(d, run)


def run(args) -> int:
    from ..envmap import load_envmap

    if args.envmap is not None:
        load_envmap(args.envmap)  # refuse a missing or corrupt map before minutes of simulation and fitting
    report = run_demo(Path(args.out), resolution=args.resolution, envmap=args.envmap,
                      image_size=args.image_size, quiet=args.quiet)
    print(f"wrote {args.out}/ (report.md, report.json, settings.json, *.exr, *.png)")
    print(f"diffuse albedo error (median) {100 * report['diffuse_albedo_rel_error_median']:.3f}%, "
          f"roughness error (median) {100 * report['roughness_rel_error_median']:.3f}%, "
          f"relit PSNR {report['relit_from_fit_vs_image_based_psnr_db']:.1f} dB")
    return 0


def run_demo(out: Path, resolution: int = 128, envmap: Path | None = None, image_size: int = 384,
             quiet: bool = False) -> dict:
    """Run the whole demo into ``out``; returns the report as a dict."""
    import brdf
    import stage
    from brdf import atomic_write_text

    from ..envmap import light_weights, load_envmap
    from ..fitting import _driver as _fit
    from ..image._preview import dilate, texture_view
    from ..image._tonemap import to_uint8, tonemap
    from ..io import write_exr, write_png
    from ..render import relight_olat

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    envmap = envmap_path(None if envmap is None else str(envmap))
    times = {}
    t0 = time.perf_counter()
    mesh = stage.load_head()
    surface = stage.texel_samples(mesh, resolution)
    rig = stage.light_stage_x()
    camera = stage.look_at((0.0, 0.0, 1300.0), fov_deg=11.0, width=image_size, height=image_size)
    times["geometry_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    with bar(surface.num_samples * rig.num_lights, "visibility (rays)", quiet, leave=True) as b:
        light_vis = stage.light_visibility(stage_mesh := mesh, surface, rig, chunk=1 << 18, progress=b)
    cam_vis = stage.camera_visibility(stage_mesh, surface, [camera])
    times["visibility_s"] = time.perf_counter() - t0
    seen = np.nonzero(cam_vis[0])[0]
    surface = surface.subset(seen)
    light_vis = light_vis[seen]
    cam_vis = cam_vis[:, seen]

    rho_true, f0_true, alpha_true = demo_material(surface)
    truth = brdf.lambert_ggx(rho_true, f0_true, alpha_true)
    t0 = time.perf_counter()
    with bar(rig.num_lights, "simulate (lights)", quiet, leave=True) as b:
        capture = stage.simulate(surface, rig, [camera], truth, light_vis, cam_vis, progress=b)
    times["simulate_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    with bar(surface.num_samples, "fit (texels)", quiet, leave=True) as b:
        fitted = _fit.fit(capture, surface, progress=b)
    times["fit_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    env = load_envmap(envmap)
    weights = light_weights(env, rig.directions, rig.center_irradiance)
    relit_ibr = np.asarray(relight_olat(capture.radiance, weights))[0]
    maps = fitted.maps(surface)
    refit = stage.simulate(maps.frame(surface), rig, [camera], maps.brdf(include_diffuse=True), light_vis, cam_vis)
    relit_fit = np.asarray(relight_olat(refit.radiance, weights))[0]
    times["relight_s"] = time.perf_counter() - t0

    # Errors over lit texels (at least 8 valid lights), against the simulated truth.
    lit = np.asarray(fitted.observed) >= 8
    rel = lambda est, ref: np.abs(np.asarray(est) - np.asarray(ref)) / np.asarray(ref)  # noqa: E731
    err_rho = rel(fitted.rho_d, rho_true)[lit]
    err_alpha = rel(fitted.alpha[:, :1], alpha_true)[lit]
    mse = float(np.mean((relit_fit - relit_ibr) ** 2))
    peak = float(np.max(relit_ibr))
    report = {
        "texels_fitted": int(surface.num_samples),
        "lights": int(rig.num_lights),
        "texel_resolution": int(resolution),
        "envmap": str(envmap),
        "diffuse_albedo_rel_error_median": float(np.median(err_rho)),
        "diffuse_albedo_rel_error_p95": float(np.percentile(err_rho, 95)),
        "roughness_rel_error_median": float(np.median(err_alpha)),
        "roughness_rel_error_p95": float(np.percentile(err_alpha, 95)),
        "fit_failed_fraction": float(np.mean(np.asarray(fitted.failed))),
        "fit_steps_median": float(np.median(np.asarray(fitted.steps))),
        "relit_from_fit_vs_image_based_psnr_db": float(10 * np.log10(peak**2 / max(mse, 1e-30))),
        "timings_s": {k: round(v, 3) for k, v in times.items()},
    }

    # Outputs: texel-space maps (EXR) and camera-view previews (EXR + PNG).
    valid = np.zeros(surface.resolution, bool)
    valid.reshape(-1)[np.asarray(surface.texel_index)] = True
    tex = lambda x: surface.to_texture(np.asarray(x, np.float32))  # noqa: E731
    maps = {"albedo": tex(fitted.rho_d), "specular": tex(fitted.f0), "roughness": tex(fitted.alpha[:, :1]),
            "relit_image_based": tex(relit_ibr), "relit_from_fit": tex(relit_fit)}
    for name, m in maps.items():
        write_exr(out / f"{name}.exr", m)
    views = texture_view(mesh, camera, {k: dilate(v, valid) for k, v in maps.items()})
    exposure = -float(np.log2(max(np.percentile(views["relit_image_based"][views["relit_image_based"] > 0], 99), 1e-6)))
    for name, img in views.items():
        if name.startswith("relit"):
            write_exr(out / f"{name}_view.exr", img)
            write_png(out / f"{name}_view.png", to_uint8(tonemap(img, exposure=exposure, curve="filmic")))
        else:
            shown = np.repeat(img, 3, axis=-1) if img.shape[-1] == 1 else img
            write_png(out / f"{name}_view.png", to_uint8(tonemap(shown, curve="none")))
    side = [to_uint8(tonemap(views[k], exposure=exposure, curve="filmic"))
            for k in ("relit_image_based", "relit_from_fit")]
    write_png(out / "preview.png", np.concatenate(side, axis=1))
    settings = {"command": "relight demo", "out": str(out), "resolution": resolution, "envmap": str(envmap),
                "image_size": image_size, "rig": "light_stage_x", "camera": "look_at (0, 0, 1300) mm, fov 11 deg"}
    atomic_write_text(out / "settings.json", json.dumps(settings, indent=2))
    atomic_write_text(out / "report.json", json.dumps(report, indent=2))
    atomic_write_text(out / "report.md", _report_md(report))
    return report


def _report_md(r: dict) -> str:
    t = r["timings_s"]
    return "\n".join([
        "# relight demo report", "",
        f"{r['texels_fitted']} texels seen by the camera, {r['lights']} lights (ICT Light Stage X), "
        f"texel grid {r['texel_resolution']}^2, environment `{Path(r['envmap']).name}`.", "",
        "| quantity (fit against the simulated truth, noise-free) | median | 95th percentile |",
        "| --- | --- | --- |",
        f"| diffuse albedo relative error | {r['diffuse_albedo_rel_error_median']:.2e} | "
        f"{r['diffuse_albedo_rel_error_p95']:.2e} |",
        f"| roughness relative error | {r['roughness_rel_error_median']:.2e} | {r['roughness_rel_error_p95']:.2e} |",
        "",
        f"Failed samples: {100 * r['fit_failed_fraction']:.2f}%. Median LM steps: {r['fit_steps_median']:.0f}.",
        f"Relit from the fitted maps vs image-based relighting of the capture: "
        f"PSNR {r['relit_from_fit_vs_image_based_psnr_db']:.1f} dB.", "",
        "| stage | seconds |", "| --- | --- |",
        *[f"| {k[:-2]} | {v:.2f} |" for k, v in t.items()], "",
    ])

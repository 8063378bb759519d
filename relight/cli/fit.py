"""``relight fit``: fit per-texel reflectance to a texel-space capture folder
and write the texture set, a Mitsuba 3 scene, previews and a report."""

from __future__ import annotations

import inspect
import time
from pathlib import Path

import numpy as np

import stage
from brdf import atomic_write_text

from ..fitting._driver import SOLVERS as METHODS
from ..image._preview import texture_view
from ..io import is_map_set, load_texel_capture, read_maps, texture_set, write_exr, write_texture_set
from ..materials._maps import MODELS, SUBSURFACE
from ._common import (
    CLIError,
    add_envmap,
    add_out,
    bar,
    ensure_out,
    envmap_path,
    finish_parser,
    write_json,
    write_preview,
    write_settings,
)

# relight.fit's rungs (subsurface is fitted afterwards by fit_subsurface) and the ladder.
FIT_MODELS = MODELS[:SUBSURFACE] + ("auto",)


def add_parser(sub) -> None:
    p = sub.add_parser("fit", help="fit reflectance maps to a capture folder; write a texture set + Mitsuba scene",
                       description="Fit the per-texel reflectance model to a texel-space capture folder (from "
                                   "`relight simulate`) and write the texture set, a Mitsuba 3 scene, previews, "
                                   "report.json/report.md and settings.json.")
    p.add_argument("capture", metavar="CAPTURE_DIR", help="capture folder (capture.json, rig.json, cameras.json)")
    add_out(p, "output folder for the map set")
    p.add_argument("--method", default="lm", choices=METHODS,
                   help="least-squares solver: lm (Levenberg-Marquardt, default), gn, dogleg, bfgs")
    p.add_argument("--model", default=None, choices=FIT_MODELS,
                   help="reflectance model: a rung of the ladder or auto (per-texel selection on held-out lights); "
                        "default: relight.fit's own (ggx)")
    p.add_argument("--normals", action="store_true", help="also fit the shading normal")
    add_envmap(p, "environment map for the Mitsuba scene")
    finish_parser(p, run)


def fit_kwargs(fit_fn, method: str, model: str | None = None, normals: bool = False) -> dict:
    """Options for ``relight.fit`` that this build supports (checked by signature);
    asking for one it lacks is an error, not silently ignored."""
    params = inspect.signature(fit_fn).parameters
    out = {}
    if "method" in params:
        out["method"] = method
    elif "solver" in params:
        out["solver"] = method
    elif method != "lm":
        raise CLIError(f"--method {method}: this version of relight.fit supports only 'lm' (Levenberg-Marquardt)")
    if model is not None:
        if "model" not in params:
            raise CLIError(f"--model {model}: this version of relight.fit fits one model only")
        out["model"] = model
    if normals:
        if "normals" not in params:
            raise CLIError("--normals: this version of relight.fit does not fit normals")
        out["normals"] = True
    return out


def run(args) -> int:
    import relight

    from ..envmap import load_envmap
    from ..io import write_mitsuba_scene

    envmap = envmap_path(args.envmap)
    load_envmap(envmap)  # refuse a missing or corrupt map before the fit, not after
    kwargs = fit_kwargs(relight.fit, args.method, args.model, args.normals)
    times = {}
    t0 = time.perf_counter()
    capture_dir = Path(args.capture)
    with bar(None, "read capture (images)", args.quiet) as b:
        capture, surface, mesh, metadata = load_texel_capture(capture_dir, progress=b)
    info = metadata["surface"]
    times["read_s"] = time.perf_counter() - t0
    out = ensure_out(args.out)

    t0 = time.perf_counter()
    with bar(surface.num_samples, "fit (texels)", args.quiet) as b:
        fitted = relight.fit(capture, surface, progress=b, **kwargs)
    maps = fitted.maps(surface)
    times["fit_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    cams = [stage.camera_to_dict(c, f"cam{i:03d}") for i, c in enumerate(capture.cameras)]
    # The capture's rig travels with the maps: `relight render --method rig` uses it by default.
    stage.save_rig(out / "rig.json", capture.rig)
    textures = texture_set(maps, surface, surface_info=info,
                           metadata={"capture": str(capture_dir.resolve()), "fit_options": kwargs, "cameras": cams,
                                     "rig": "rig.json", "source": "relight fit"})
    write_texture_set(out, textures)
    cam = capture.cameras[0]
    if cam.orthographic:
        scene = None
    else:
        scene = write_mitsuba_scene(out, mesh, textures, cam, envmap)
    # Previews: texel-space maps and the maps as the capture's first camera sees them.
    texel_previews = (("albedo", textures.albedo), ("specular", textures.specular),
                      ("roughness", textures.alpha[..., :1]))
    for name, img in texel_previews:
        write_preview(out / f"{name}.png", img, exposure=0.0, curve="none")
    views = texture_view(mesh, cam, {"albedo": textures.albedo, "roughness": textures.alpha[..., :1]})
    for name, img in views.items():
        write_exr(out / f"{name}_view.exr", img)
        write_preview(out / f"{name}_view.png", img, exposure=0.0, curve="none")
    times["write_s"] = time.perf_counter() - t0

    report = _report(fitted, surface, Path(args.capture), times)
    write_json(out / "report.json", report)
    atomic_write_text(out / "report.md", _report_md(report))
    write_settings(out, "fit", args, capture=str(Path(args.capture).resolve()), envmap=str(envmap),
                   fit_options=kwargs, mesh=info, samples=surface.num_samples,
                   mitsuba_scene=None if scene is None else str(scene))
    if not args.quiet:
        print(f"wrote {out}/ (texture set, scene.xml, report.md); {report['samples']} texels, "
              f"{100 * report['failed_fraction']:.1f}% flagged")
    return 0


def _report(fitted, surface, capture_dir: Path, times) -> dict:
    failed = np.asarray(fitted.failed)
    r = {
        "samples": int(surface.num_samples),
        "failed_fraction": float(np.mean(failed)),
        "residual_rms_median": float(np.median(np.asarray(fitted.residual)[~failed])) if (~failed).any() else None,
        "steps_median": float(np.median(np.asarray(fitted.steps))),
        "observed_median": float(np.median(np.asarray(fitted.observed))),
        "timings_s": {k: round(v, 3) for k, v in times.items()},
    }
    if getattr(fitted, "model", None) is not None:
        counts = np.bincount(np.asarray(fitted.model).reshape(-1), minlength=len(MODELS))
        r["model_counts"] = {m: int(c) for m, c in zip(MODELS, counts, strict=False)}
    if hasattr(fitted, "unresolved"):
        r["unresolved_fraction"] = float(np.mean(np.asarray(fitted.unresolved)))
    truth_dir = capture_dir / "truth"
    if is_map_set(truth_dir):
        truth, _ = read_maps(truth_dir)
        t = truth.maps(surface)
        ok = ~failed
        rel = lambda a, b: (np.abs(np.asarray(a) - np.asarray(b)) / np.abs(np.asarray(b)))[ok]  # noqa: E731
        ea = rel(fitted.rho_d, t.rho_d)
        er = rel(np.asarray(fitted.alpha)[:, :1], np.asarray(t.alpha)[:, :1])
        r["against_truth"] = {
            "diffuse_albedo_rel_error_median": float(np.median(ea)),
            "diffuse_albedo_rel_error_p95": float(np.percentile(ea, 95)),
            "roughness_rel_error_median": float(np.median(er)),
            "roughness_rel_error_p95": float(np.percentile(er, 95)),
        }
    return r


def _report_md(r: dict) -> str:
    lines = ["# relight fit report", "",
             f"{r['samples']} texels fitted; {100 * r['failed_fraction']:.2f}% flagged (solver failure or fewer "
             f"than 8 valid lights). Median RMS residual {r['residual_rms_median']}, median steps "
             f"{r['steps_median']:.0f}, median valid observations {r['observed_median']:.0f}.", ""]
    if "against_truth" in r:
        a = r["against_truth"]
        lines += ["| against the simulated truth | median | 95th percentile |", "| --- | --- | --- |",
                  f"| diffuse albedo relative error | {a['diffuse_albedo_rel_error_median']:.2e} | "
                  f"{a['diffuse_albedo_rel_error_p95']:.2e} |",
                  f"| roughness relative error | {a['roughness_rel_error_median']:.2e} | "
                  f"{a['roughness_rel_error_p95']:.2e} |", ""]
    if "model_counts" in r:
        lines += ["Texels per model: " + ", ".join(f"{k} {v}" for k, v in r["model_counts"].items() if v) + ".", ""]
    lines += ["| stage | seconds |", "| --- | --- |",
              *[f"| {k[:-2]} | {v:.2f} |" for k, v in r["timings_s"].items()], ""]
    return "\n".join(lines)


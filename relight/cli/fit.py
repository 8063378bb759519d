"""``relight fit``: fit per-texel reflectance to a texel-space capture folder,
or to a camera-space photo capture (docs/capture_layout.md) resampled onto a
mesh's texel grid (``relight.io.photos_to_texels``), and write the texture set,
a Mitsuba 3 scene, previews and a report.

``--subsurface region|texel|auto`` (texel-space captures) runs
``relight.fit_subsurface`` after the BRDF fit: the diffuse mean free path
(mm, per channel; per region of ``--regions``, per texel, or the held-out
ladder of none / region / texel) and the profile albedo; the map set then
carries mean_free_path.exr and model.exr = subsurface where chosen.

Streaming (docs/scaling.md): a texel-space capture folder or store is not
loaded; ``relight.fitting.fit_parts`` reads it ``--block`` texels at a time
(``relight.io.open_texel_capture``) on ``--devices`` and writes each finished
block to ``OUT/.parts/`` at once; ``relight.fitting.merge_parts`` then makes
the fit. ``--resume`` keeps the parts of an earlier run of the same fit (a
killed run, or a finished one: no block is refitted); without it they are
deleted first. ``--subsurface`` needs the whole capture in memory (its
operator couples texels), so it loads it as before."""

from __future__ import annotations

import argparse
import inspect
import shutil
import time
from pathlib import Path

import numpy as np

# stage, brdf, JAX and the rest of relight are imported inside the functions that use them, so that
# `relight fit --help` builds its parser without them.
from ._common import (
    INDEX_FRAMES,
    INDEX_SIZE,
    PREVIEW_MIN_PX,
    CLIError,
    add_envmap,
    add_index_flag,
    add_mesh_flags,
    add_out,
    add_rig_file_flags,
    at_least,
    bar,
    check_out,
    envmap_path,
    finish_parser,
    mesh_from_args,
    output_set,
    summary,
    upscale_nearest,
    warn_mesh_size,
    write_index_page,
    write_json,
    write_map_previews,
    write_preview,
    write_settings,
    writing,
)

# relight.fit's rungs (relight.MODELS up to subsurface, which fit_subsurface fits afterwards) and the ladder,
# and its solvers (relight.SOLVERS): spelled here so that the parser needs no JAX; tests/relight/test_cli_ux.py
# checks them against the library's.
FIT_MODELS = ("lambert", "blinn_phong", "ggx", "ggx_aniso", "auto")
METHODS = ("lm", "optx-lm", "gn", "dogleg", "bfgs")
# --subsurface: off, or fit_subsurface's per= (region: one mfp per region of --regions; texel: per texel; auto:
# the ladder none / region / texel by held-out error).
SUBSURFACE_MODES = ("off", "region", "texel", "auto")
# The relative index of the subsurface Fresnel transmittances when the capture does not record one (skin's).
DEFAULT_ETA = 1.4
# The result-set folder of fit_parts inside --out: hidden, it is not part of the map set.
PARTS = ".parts"


def add_parser(sub) -> None:
    p = sub.add_parser("fit", help="fit reflectance maps to a capture folder; write a texture set + Mitsuba scene",
                       description="Fit the per-texel reflectance model to a texel-space capture folder (from "
                                   "`relight simulate`), or to a camera-space photo capture (with --mesh: the "
                                   "photographs are resampled onto the mesh's texel grid), and write the texture "
                                   "set, a Mitsuba 3 scene, previews, report.json/report.md and settings.json.")
    p.add_argument("capture", metavar="CAPTURE_DIR",
                   help="capture folder (capture.json, rig.json, cameras.json): texel-space or photos")
    add_mesh_flags(p, "photo captures (required; a texel capture records its own): the subject's mesh with UVs, "
                      "in the cameras' frame, or 'head' for the bundled head")
    p.add_argument("--resolution", type=int, default=256, help="photo captures: texel grid N x N (default 256)")
    p.add_argument("--grazing-deg", type=float, default=80.0,
                   help="photo captures: drop views more than this far from a texel's normal (default 80)")
    p.add_argument("--min-views", type=int, default=1,
                   help="photo captures: texels seen by fewer cameras count as unseen (default 1)")
    add_rig_file_flags(p)
    p.add_argument("--subsample", type=int, default=1,
                   help="DiLiGenT folders: fit every k-th pixel in x and y (quick looks; default 1: all)")
    add_out(p, "output folder for the map set")
    p.add_argument("--solver", default=None, choices=METHODS,
                   help=f"least-squares solver: {', '.join(METHODS)} (default: lm, Levenberg-Marquardt)")
    # The flag's old name: `relight render --method` is the relighting method, so fit's solver has its own name.
    p.add_argument("--method", default=None, choices=METHODS, help=argparse.SUPPRESS)
    p.add_argument("--model", default=None, choices=FIT_MODELS,
                   help="reflectance model: a rung of the ladder or auto (per-texel selection on held-out lights); "
                        "default: relight.fit's own (ggx)")
    p.add_argument("--normals", action="store_true", help="also fit the shading normal")
    p.add_argument("--subsurface", default="off", choices=SUBSURFACE_MODES,
                   help="texel-space captures: after the BRDF fit, fit subsurface scattering (the diffuse mean free "
                        "path, mm, per channel): region (one per region of --regions; default one region), texel "
                        "(per texel), auto (none / region / texel per texel by held-out error); default off")
    p.add_argument("--regions", default=None, metavar="LABELS",
                   help="with --subsurface region|auto: a label map on the texel grid (.png: each distinct colour "
                        "a region; .exr: integer labels in the first channel; nearest texel if another size)")
    p.add_argument("--eta", type=float, default=None,
                   help="with --subsurface: relative index of refraction of the Fresnel transmittances (default: "
                        f"the capture's metadata.subsurface.eta, else {DEFAULT_ETA})")
    p.add_argument("--passes", type=int, default=1,
                   help="with --subsurface: BRDF / subsurface alternations (relight.fit_with_subsurface: the lobe "
                        "refitted against the predicted subsurface radiance; default: 1, the plain sequence)")
    p.add_argument("--block", type=int, default=4096, metavar="N",
                   help="texels read, fitted and written per block: the memory knob (about 13-40 KiB per texel of "
                        "a block); any N gives the same maps (default 4096)")
    p.add_argument("--devices", default="all", metavar="N|all",
                   help="JAX devices to split each solver chunk over: the first N local devices, or all (default)")
    p.add_argument("--resume", action="store_true",
                   help=f"keep the finished blocks of an earlier run of this fit in OUT/{PARTS}/ (a killed run; a "
                        "finished one costs no fitting); refused if the capture, surface or a setting changed. "
                        f"Without it, OUT/{PARTS}/ is cleared and every block is fitted")
    add_envmap(p, "environment map for the Mitsuba scene and index.html's rotation sweep")
    add_index_flag(p)
    finish_parser(p, run)


def parse_devices(spec: str):
    """``--devices``: "all" -> None (every local device), N -> N (1..the local device count); CLIError else."""
    import jax

    n_local = len(jax.local_devices())
    if str(spec).strip().lower() == "all":
        return None
    try:
        n = int(spec)
    except ValueError:
        raise CLIError(f"--devices {spec}: an integer N or 'all'") from None
    if not 1 <= n <= n_local:
        raise CLIError(f"--devices {spec}: must be between 1 and the {n_local} local device(s) "
                       f"({jax.default_backend()}), or 'all'")
    return n


def resolve_solver(args) -> str:
    """``--solver``, or ``--method`` (its deprecated alias: one warning on stderr), else "lm"; CLIError when
    both are given and differ. Sets ``args.solver`` (settings.json records the resolved name)."""
    import sys

    if args.method is not None:
        print("relight fit: warning: --method is deprecated for fit; use --solver (render's --method is the "
              "relighting method)", file=sys.stderr)
        if args.solver is not None and args.solver != args.method:
            raise CLIError(f"--method {args.method} and --solver {args.solver}: give one (--solver)")
    args.solver = args.solver or args.method or "lm"
    return args.solver


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
        raise CLIError(f"--solver {method}: this version of relight.fit supports only 'lm' (Levenberg-Marquardt)")
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
    from ..io import is_diligent_folder, is_photo_capture

    envmap = envmap_path(args.envmap)
    load_envmap(envmap)  # refuse a missing or corrupt map before the fit, not after
    kwargs = fit_kwargs(relight.fit, resolve_solver(args), args.model, args.normals)
    at_least("--block", args.block, 1)
    devices = parse_devices(args.devices)
    times = {}
    t0 = time.perf_counter()
    capture_dir = Path(args.capture)
    diligent = is_diligent_folder(capture_dir)
    photos = not diligent and is_photo_capture(capture_dir)
    _check_subsurface_flags(args, capture_dir, "diligent" if diligent else "photos" if photos else "texel")
    if diligent:
        return _run_diligent(args, capture_dir, {**kwargs, "block": args.block, "devices": devices})
    if args.subsample != 1:
        raise CLIError("--subsample applies to DiLiGenT folders only")
    # Refused before the capture is read; output_set checks again with the folder locked.
    check_out(args.out, "fit", keep=(PARTS,))
    with output_set(args.out, "fit", args.quiet, keep=(PARTS,)) as tmp:
        return _run_texel(args, capture_dir, photos, kwargs, devices, envmap, times, t0, Path(args.out), tmp)


def _run_texel(args, capture_dir: Path, photos: bool, kwargs: dict, devices, envmap: Path, times: dict, t0: float,
               out: Path, tmp: Path) -> int:
    """The fit of a texel-space or photo capture into the result set built at ``tmp`` (swapped to ``out``
    by the caller); the parts go to ``out/.parts``, which survives a killed run (--resume)."""
    import jax

    import stage
    from brdf import atomic_write_text

    from ..image._preview import texture_view
    from ..io import texture_set, write_exr, write_mitsuba_scene
    from ..io._texture_set import write_texture_set_files

    metadata = {}
    coverage = None
    if photos:
        capture, surface, mesh, info, coverage = _ingest_photos(args, capture_dir)
    else:
        capture, surface, mesh, metadata = _read_texel(args, capture_dir)
        info = metadata["surface"]
    times["read_s"] = time.perf_counter() - t0
    out.mkdir(parents=True, exist_ok=True)  # for out/.parts; the set itself is built in tmp

    t0 = time.perf_counter()
    fitted, parts = _fit_in_parts(args, capture, surface, out, kwargs, devices)
    times["fit_s"] = time.perf_counter() - t0
    sss = None
    if args.subsurface != "off":
        t0 = time.perf_counter()
        fitted, sss = _fit_subsurface(args, capture, surface, fitted, metadata,
                                      {"block": args.block, "devices": devices})
        times["subsurface_s"] = time.perf_counter() - t0
    maps = fitted.maps(surface)

    t0 = time.perf_counter()
    cams = [stage.camera_to_dict(c, f"cam{i:03d}") for i, c in enumerate(capture.cameras)]
    # The capture's rig travels with the maps: `relight render --method rig` uses it by default.
    with writing(tmp / "rig.json"):
        stage.save_rig(tmp / "rig.json", capture.rig)
    map_meta = {"capture": str(capture_dir.resolve()), "fit_options": kwargs, "cameras": cams, "rig": "rig.json",
                "source": "relight fit"}
    if sss is not None:
        map_meta["subsurface"] = sss  # its eta is what `relight render` uses
    textures = texture_set(maps, surface, surface_info=info, metadata=map_meta)
    write_texture_set_files(tmp, textures)
    cam = capture.cameras[0]
    if cam.orthographic:
        scene = None
    else:
        with writing(tmp / "scene.xml"):
            scene = out / write_mitsuba_scene(tmp, mesh, textures, cam, envmap).relative_to(tmp)
    # Previews: texel-space maps and the maps as the capture's first camera sees them.
    write_map_previews(tmp, textures.albedo, textures.specular, textures.alpha[..., :1])
    if sss is not None:
        # mean_free_path.png: mfp / the largest mfp of the set (one scale for R, G, B), linear.
        top = float(np.max(textures.mfp))
        write_preview(tmp / "mean_free_path.png", textures.mfp / max(top, 1e-12), exposure=0.0, curve="none",
                      min_px=PREVIEW_MIN_PX)
    views = texture_view(mesh, cam, {"albedo": textures.albedo, "roughness": textures.alpha[..., :1]})
    for name, img in views.items():
        with writing(tmp / f"{name}_view.exr"):
            write_exr(tmp / f"{name}_view.exr", img)
        write_preview(tmp / f"{name}_view.png", img, exposure=0.0, curve="none")
    if coverage is not None:
        _write_coverage(tmp, surface, coverage)
    times["write_s"] = time.perf_counter() - t0

    # The report reads the fit on the host: NumPy leaves, so its per-texel tests compile nothing.
    fitted = jax.tree_util.tree_map(np.asarray, fitted)
    report = _report(fitted, surface, Path(args.capture), times, normals=args.normals)
    report["parts"] = parts
    if sss is not None:
        report["subsurface"] = _subsurface_report(fitted, surface, Path(args.capture), sss,
                                                  times["subsurface_s"])
    if coverage is not None:
        report["photos"] = coverage.to_dict()
    write_json(tmp / "report.json", report)
    with writing(tmp / "report.md"):
        atomic_write_text(tmp / "report.md", _report_md(report))
    write_settings(tmp, "fit", args, capture=str(Path(args.capture).resolve()), envmap=str(envmap),
                   fit_options=kwargs, mesh=info, samples=surface.num_samples,
                   input="photos" if photos else "texel", subsurface=sss,
                   mitsuba_scene=None if scene is None else str(scene),
                   block=args.block, devices=parts["devices"], parts=str(out / PARTS),
                   streamed=not isinstance(capture, stage.Capture))
    if not args.no_index:
        write_index_page(tmp, lambda: _index_sweeps(tmp, photos, envmap, maps, surface, mesh, capture), "fit",
                         args.quiet, location=out)
    if report["failed_fraction"] >= 0.5:
        import sys

        print(f"relight fit: warning: {100 * report['failed_fraction']:.0f}% of the texels are flagged (a solver "
              "failure, or fewer than 8 valid lights: a rig with more lights, or more cameras, covers them); their "
              "maps hold the defaults", file=sys.stderr)
    if summary(args):
        tail = ""
        if sss is not None:
            ss = report["subsurface"]
            med = ss["mfp_median_mm"]
            tail = (f"; subsurface ({args.subsurface}) on {ss['subsurface_samples']} texels" +
                    ("" if med is None else ", median mfp " + "/".join(f"{x:.3g}" for x in med) + " mm (R/G/B)"))
        resumed = f"; {parts['resumed_blocks']} of {parts['blocks']} blocks resumed" * bool(parts["resumed_blocks"])
        print(f"wrote {out}/ (texture set, scene.xml, report.md); {report['samples']} texels, "
              f"{100 * report['failed_fraction']:.1f}% flagged{tail}{resumed}")
    return 0


def _index_sweeps(tmp: Path, photos: bool, envmap: Path, maps, surface, mesh, capture):
    """index.html's slider: the capture the maps were fitted from, relit image-based (read back whole if small
    enough: ``relight.view.folder_sweeps``); without one (a photo capture, a large one), the fitted maps
    rendered model-based through the capture's rig."""
    from ..envmap import load_envmap
    from ..view import folder_sweeps, maps_sweep

    rows, note = ([], None) if photos else folder_sweeps(tmp, envmap, INDEX_FRAMES, INDEX_SIZE, model=False)
    if rows:
        return rows, note
    return [maps_sweep(maps, surface, mesh, capture.cameras[0], load_envmap(envmap), rig=capture.rig,
                       frames=INDEX_FRAMES, size=INDEX_SIZE,
                       label="the fitted maps rendered model-based (the capture's rig)")], None


def _read_texel(args, capture_dir: Path):
    """A texel-space capture folder or store: opened lazily (``open_texel_capture``: the mask is read
    to find the seen texels, the radiance block by block later), or, with --subsurface, loaded whole."""
    from ..io import load_texel_capture, open_texel_capture

    _refuse_photo_flags(args, f"{capture_dir} is a texel-space capture, which records its mesh and rig "
                              "(they apply to photo captures)")
    if args.subsurface != "off":
        # fit_subsurface couples texels through the diffusion operator: it takes the capture whole.
        with bar(None, "read capture (images)", args.quiet, waiting="reading") as b:
            return load_texel_capture(capture_dir, progress=b)
    with bar(None, "read mask", args.quiet, waiting="reading") as b:
        return open_texel_capture(capture_dir, progress=b)


def _clear_parts(folder: Path) -> None:
    """Delete an earlier run's result set at ``folder`` (only what fit_parts writes there; CLIError if
    it holds anything else, so a user's folder is never removed)."""
    if not folder.exists():
        return
    from ..fitting._parts import MANIFEST

    own = folder.is_dir() and all(p.is_file() and (p.name == MANIFEST or p.name.startswith(("part_", ".")))
                                  for p in folder.iterdir())
    if not own:
        raise CLIError(f"{folder}: exists and is not a fit's parts folder; refusing to delete it (move it away)")
    shutil.rmtree(folder)


def _fit_in_parts(args, capture, surface, out: Path, kwargs: dict, devices):
    """``relight.fitting.fit_parts`` into ``out/.parts`` (cleared first unless --resume), then
    ``merge_parts``: the Fit (that of one ``relight.fit`` call with these settings, bit for bit) and the
    report's ``parts`` entry (blocks, how many fitted now, how many resumed)."""
    import jax

    from ..fitting import PartsFingerprintError, fit_parts, merge_parts
    from ..io._resultset import kill_point

    folder = out / PARTS
    if not args.resume:
        _clear_parts(folder)
    fitted_blocks = []

    def on_block(s, e, _):
        fitted_blocks.append((s, e))
        kill_point("block")  # tests/relight/test_kill.py: killed with the map set half replaced, as reported

    with bar(surface.num_samples, "fit (texels)", args.quiet) as b:
        try:
            fit_parts(capture, surface, folder, block=args.block, process_index=0, process_count=1,
                      on_block=on_block, progress=b, devices=devices, **kwargs)
        except PartsFingerprintError as err:
            raise CLIError(f"--resume: {folder} holds the parts of another fit (the capture, the surface or a "
                           f"setting such as --model, --solver, --normals, --block or --devices changed): rerun "
                           f"without --resume to fit afresh ({err})") from None
    fitted = merge_parts(folder, surface)
    n_blocks = -(-surface.num_samples // args.block)
    ndev = len(jax.local_devices()) if devices is None else int(devices)
    return fitted, {"folder": PARTS, "block": int(args.block), "blocks": n_blocks, "devices": ndev,
                    "fitted_blocks": len(fitted_blocks), "resumed_blocks": n_blocks - len(fitted_blocks)}


def _check_subsurface_flags(args, capture_dir: Path, kind: str) -> None:
    """CLIError on --subsurface / --regions / --eta that do not go together or
    with this kind of input (subsurface fitting takes texel-space captures)."""
    if args.passes < 1:
        raise CLIError(f"--passes {args.passes}: must be >= 1")
    if args.subsurface == "off" and args.passes != 1:
        raise CLIError("--passes: needs --subsurface region|texel|auto")
    if args.subsurface == "off" and (args.regions is not None or args.eta is not None):
        raise CLIError(f"{'--regions' if args.regions is not None else '--eta'}: needs --subsurface "
                       "region|texel|auto")
    if args.regions is not None and args.subsurface == "texel":
        raise CLIError("--regions: --subsurface texel fits every texel on its own; regions apply to region|auto")
    if args.regions is not None and not Path(args.regions).is_file():
        raise CLIError(f"--regions {args.regions}: no such label map")
    if args.eta is not None and not (np.isfinite(args.eta) and 1.0 < args.eta <= 3.0):
        raise CLIError(f"--eta {args.eta}: must be in (1, 3]")
    if args.subsurface == "off" or kind == "texel":
        return
    what = {"diligent": "a DiLiGenT folder (one view of pixels, no surface to scatter over)",
            "photos": "a photo capture"}[kind]
    raise CLIError(f"--subsurface {args.subsurface}: {capture_dir} is {what}; subsurface fitting takes "
                   "texel-space captures only (`relight simulate`'s)")


def _read_regions(path: str, surface) -> np.ndarray:
    """Labels [P] (0..R-1) of ``--regions`` at the surface's samples: a PNG's
    distinct colours or an EXR's first channel (rounded to integers), at the
    texel itself when the map is on the texel grid's size, else the nearest
    texel to the sample's uv."""
    from ..io import read_png

    p = Path(path)
    if not p.is_file():
        raise CLIError(f"--regions {path}: no such label map")
    suffix = p.suffix.lower()
    try:
        if suffix == ".png":
            img = np.asarray(read_png(p))
            img = img[..., None] if img.ndim == 2 else img
            _, lab = np.unique(img.reshape(-1, img.shape[-1]), axis=0, return_inverse=True)
            lab = lab.reshape(img.shape[:2])
        elif suffix == ".exr":
            from ..io import read_exr

            ch = np.asarray(read_exr(p), np.float64)[..., 0]
            if not np.all(np.isfinite(ch)):
                raise CLIError(f"--regions {path}: NaN or Inf labels")
            lab = np.rint(ch).astype(np.int64)
        else:
            raise CLIError(f"--regions {path}: a label map is a .png or an .exr")
    except ValueError as err:
        raise CLIError(f"--regions {path}: {err}") from None
    H, W = surface.resolution
    if lab.shape == (H, W):
        at = lab.reshape(-1)[np.asarray(surface.texel_index)]
    else:
        uv = np.asarray(surface.uv, np.float64)
        h, w = lab.shape
        x = np.clip(np.floor(uv[:, 0] * w), 0, w - 1).astype(int)
        y = np.clip(np.floor((1 - uv[:, 1]) * h), 0, h - 1).astype(int)
        at = lab[y, x]
    # Renumber to 0..R-1 over the fitted samples: fit_subsurface takes contiguous labels.
    return np.unique(at, return_inverse=True)[1].reshape(-1).astype(np.int64)


def _subsurface_md(ss: dict) -> list[str]:
    fmt = lambda v: "-" if v is None else " / ".join(f"{x:.3g}" for x in v)  # noqa: E731
    regions = "" if ss["regions"] is None else f", {ss['regions']['count']} regions of {ss['regions']['file']}"
    lines = ["## Subsurface scattering", "",
             f"Mode {ss['mode']}{regions}, eta {ss['eta']:g} ({ss['eta_from']}): {ss['subsurface_samples']} of "
             f"{ss['samples']} texels on the subsurface rung (the others keep the BRDF's local Lambert term); "
             f"{ss['seconds']:.2f} s.", "",
             "| mean free path (mm) | R / G / B |", "| --- | --- |",
             f"| median over subsurface texels | {fmt(ss['mfp_median_mm'])} |"]
    if "identified_fraction" in ss:
        lines.append(f"| identified fraction (1-sigma of ln mfp < {ss['identified_sigma']:g}) | "
                     f"{fmt(ss['identified_fraction'])} |")
    if "against_truth" in ss:
        a = ss["against_truth"]
        lines += [f"| simulated truth, median | {fmt(a['truth_mfp_median_mm'])} |",
                  f"| relative error vs truth, median | {fmt(a['mfp_rel_error_median'])} |"]
    lines.append("")
    if "rung_counts" in ss:
        c = ss["rung_counts"]
        lines += [f"Texels per rung: none {c['none']}, region {c['region']}, texel {c['texel']}.", ""]
    if "against_truth" in ss:
        lines += [f"Subsurface / local choice agrees with the truth on "
                  f"{100 * ss['against_truth']['model_agreement']:.1f}% of the texels.", ""]
    return lines


def _fit_subsurface(args, capture, surface, fitted, metadata: dict, stream: dict | None = None):
    """``relight.fit_subsurface`` with ``--subsurface``'s mode (``per=``; the
    region mode, fit_subsurface's default, passes none), ``--regions`` and eta
    (``--eta``, else the capture's metadata.subsurface.eta, else 1.4); ``stream``
    (--block / --devices) goes to the BRDF refits of ``--passes`` > 1. Returns
    (the new Fit, the settings dict recorded in maps.json and the report)."""
    import relight

    recorded = (metadata.get("subsurface") or {}).get("eta")
    eta = float(args.eta if args.eta is not None else recorded if recorded is not None else DEFAULT_ETA)
    kw = {"eta": eta}
    if args.subsurface != "region":
        if "per" not in inspect.signature(relight.fit_subsurface).parameters:
            raise CLIError(f"--subsurface {args.subsurface}: this version of relight.fit_subsurface fits one mean "
                           "free path per region only (use --subsurface region)")
        kw["per"] = args.subsurface
    regions = None
    if args.regions is not None:
        regions = _read_regions(args.regions, surface)
        kw["regions"] = regions
    with bar(None, "fit subsurface", args.quiet) as b:
        if args.passes > 1:
            fo = {**fit_kwargs(relight.fit, args.solver), **(stream or {})}
            rest = {k: v for k, v in kw.items() if k != "per"}
            g = relight.fit_with_subsurface(capture, surface, model=args.model or "ggx", normals=args.normals,
                                            per=args.subsurface, passes=args.passes, first=fitted,
                                            fit_options=fo, progress=b, **rest)
        else:
            g = relight.fit_subsurface(capture, surface, fitted, progress=b, **kw)
    sss = {"mode": args.subsurface, "eta": eta, "passes": int(args.passes),
           "eta_from": "--eta" if args.eta is not None else "capture" if recorded is not None else "default",
           "regions": None if regions is None else {"file": str(Path(args.regions).resolve()),
                                                    "count": int(regions.max()) + 1}}
    return g, sss


def _subsurface_report(fitted, surface, capture_dir: Path, sss: dict, seconds: float) -> dict:
    """report.json's ``subsurface``: texels switched to the subsurface rung,
    the per-channel median mean free path over them (mm), the ladder's rung
    counts and the identified fraction (where the fit reports them), and,
    for a simulated capture, the median relative error against truth/."""
    from ..io import is_map_set, read_maps
    from ..materials._maps import SUBSURFACE

    model = np.asarray(fitted.model)
    on = model == SUBSURFACE
    mfp = np.asarray(fitted.mfp, np.float64) if fitted.mfp is not None else np.zeros((len(model), 3))
    r = {**sss, "subsurface_samples": int(on.sum()), "samples": int(len(model)),
         "mfp_median_mm": np.median(mfp[on], axis=0).tolist() if on.any() else None,
         "seconds": round(seconds, 3)}
    rung = getattr(fitted, "mfp_rung", None)
    if rung is not None:
        counts = np.bincount(np.asarray(rung).reshape(-1), minlength=3)
        r["rung_counts"] = {"none": int(counts[0]), "region": int(counts[1]), "texel": int(counts[2])}
    ident = getattr(fitted, "mfp_identified", None)
    if ident is not None:
        ident = np.asarray(ident, bool)
        # Over the subsurface texels, per channel: the 1-sigma of ln mfp below Fit.IDENTIFIED_SIGMA.
        r["identified_fraction"] = ident[on].mean(axis=0).tolist() if on.any() else None
        r["identified_sigma"] = float(getattr(type(fitted), "IDENTIFIED_SIGMA", float("nan")))
    truth_dir = capture_dir / "truth"
    if is_map_set(truth_dir):
        truth, _ = read_maps(truth_dir)
        t = truth.maps(surface)
        t_on = np.asarray(t.model) == SUBSURFACE
        t_mfp = np.asarray(t.mfp, np.float64)
        both = on & t_on
        r["against_truth"] = {
            "truth_subsurface_samples": int(t_on.sum()),
            "truth_mfp_median_mm": np.median(t_mfp[t_on], axis=0).tolist() if t_on.any() else None,
            # Per channel, over texels subsurface in both.
            "mfp_rel_error_median": (np.median(np.abs(mfp[both] - t_mfp[both]) / t_mfp[both], axis=0).tolist()
                                     if both.any() else None),
            "model_agreement": float(np.mean(on == t_on)),
        }
    return r


def _angular_error_deg(n: np.ndarray, gt: np.ndarray) -> np.ndarray:
    n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    return np.degrees(np.arccos(np.clip(np.sum(n * gt, axis=-1), -1.0, 1.0)))


def _run_diligent(args, folder: Path, kwargs: dict) -> int:
    """``relight fit DILIGENT_DIR``: per pixel, the model (default Blinn-Phong, as
    scripts/eval_diligent.py) and the shading normal, in the benchmark's camera
    frame; writes normals.exr/.png, albedo.exr/.png, report.json/.md (the mean
    and median angular error against Normal_gt.mat when present, with the
    Lambertian least-squares baseline's) and settings.json."""
    import dataclasses

    from ..io import diligent_capture, read_diligent

    _refuse_photo_flags(args, f"{folder} is a DiLiGenT folder (one orthographic view, calibrated light directions)")
    if args.resume:
        raise CLIError(f"--resume: {folder} is a DiLiGenT folder, fitted in one go (no parts)")
    at_least("--subsample", args.subsample, 1)
    times = {}
    t0 = time.perf_counter()
    d = read_diligent(folder)
    if args.subsample > 1:
        keep = np.zeros_like(d.mask)
        keep[::args.subsample, ::args.subsample] = True
        d = dataclasses.replace(d, mask=d.mask & keep)
    capture, surface = diligent_capture(d)
    times["read_s"] = time.perf_counter() - t0
    check_out(args.out, "fit")
    out = Path(args.out)
    with output_set(args.out, "fit", args.quiet) as tmp:
        report = _diligent_fit(args, folder, d, capture, surface, kwargs, times, tmp)
        if not args.no_index:
            write_index_page(tmp, lambda: ([], "no rotation slider: a DiLiGenT object is lit by its calibrated "
                                               "directional lights only (no rig to relight an environment with)"),
                             "fit", args.quiet, location=out)
    if summary(args):
        e = report["diligent"].get("normal_error_deg")
        tail = "" if e is None else f"; mean normal error {e['mean']:.2f} deg"
        print(f"wrote {out}/ (normals, albedo, report.md); {surface.num_samples} pixels{tail}")
    return 0


def _diligent_fit(args, folder: Path, d, capture, surface, kwargs: dict, times: dict, out: Path) -> dict:
    """The DiLiGenT fit written into the result set being built at ``out``; returns the report."""
    import relight
    from brdf import atomic_write_text

    from ..io import lambert_normals, write_exr, write_png

    kwargs = {"model": "blinn_phong", **kwargs, "normals": True}
    t0 = time.perf_counter()
    with bar(surface.num_samples, "fit (pixels)", args.quiet) as b:
        fitted = relight.fit(capture, surface, progress=b, **kwargs)
    times["fit_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    n = np.asarray(fitted.normal, np.float64)
    normals = surface.to_texture(n.astype(np.float32))
    with writing(out / "normals.exr"):
        write_exr(out / "normals.exr", normals)
    rgb = np.where(d.mask[..., None], np.round(255 * np.clip(0.5 + 0.5 * normals, 0, 1)), 0).astype(np.uint8)
    with writing(out / "normals.png"):
        write_png(out / "normals.png", rgb)
    albedo = surface.to_texture(np.asarray(fitted.rho_d, np.float32))
    with writing(out / "albedo.exr"):
        write_exr(out / "albedo.exr", albedo)
    write_preview(out / "albedo.png", albedo, exposure=0.0, curve="none")
    times["write_s"] = time.perf_counter() - t0
    report = _report(fitted, surface, folder, times)
    report["diligent"] = {"object": folder.name, "pixels": int(surface.num_samples), "lights": int(len(d.filenames)),
                          "subsample": int(args.subsample)}
    if d.normals_gt is not None:
        gt = d.normals_gt[d.mask].astype(np.float64)
        err = _angular_error_deg(n, gt)
        base = _angular_error_deg(lambert_normals(d), gt)
        report["diligent"]["normal_error_deg"] = {
            "mean": float(err.mean()), "median": float(np.median(err)), "p95": float(np.percentile(err, 95)),
            "lambert_ls_baseline_mean": float(base.mean()), "lambert_ls_baseline_median": float(np.median(base))}
    write_json(out / "report.json", report)
    with writing(out / "report.md"):
        atomic_write_text(out / "report.md", _report_md(report))
    write_settings(out, "fit", args, capture=str(folder.resolve()), input="diligent", fit_options=kwargs,
                   samples=surface.num_samples)
    return report


def _refuse_photo_flags(args, why: str) -> None:
    """CLIError when a flag that only photo captures take was given."""
    given = [f for f, v in (("--mesh", args.mesh), ("--units", args.units), ("--scale", args.scale),
                            ("--center", args.center), ("--rig-units", args.rig_units), ("--rig-up", args.rig_up))
             if v is not None]
    if given:
        raise CLIError(f"{' / '.join(given)}: {why}")


def _ingest_photos(args, capture_dir: Path):
    """A photo capture resampled onto ``--mesh``'s texel grid: (capture, surface,
    mesh, mesh spec, PhotoTexelReport)."""
    from ..io import photos_to_texels, read_photo_capture, spec_mesh

    if args.mesh is None:
        raise CLIError(f"{capture_dir} is a photo capture (camera space): --mesh MESH is needed to resample it onto "
                       "a texel grid (a mesh with UVs in the cameras' frame, mm; 'head' for the bundled head)")
    at_least("--resolution", args.resolution, 1)
    at_least("--min-views", args.min_views, 1)
    if not 0 < args.grazing_deg <= 90:
        raise CLIError(f"--grazing-deg must be in (0, 90], got {args.grazing_deg}")
    try:
        info = mesh_from_args(args)
    except FileNotFoundError as err:
        raise CLIError(f"--mesh: {err}") from None
    mesh = spec_mesh(info, "--mesh")
    photos = read_photo_capture(capture_dir, rig_units=args.rig_units, rig_up=args.rig_up)
    warn_mesh_size("fit", mesh, photos.rig)
    with bar(photos.n_views, "photos to texels (cameras)", args.quiet) as b:
        capture, surface, coverage = photos_to_texels(photos, mesh, args.resolution, grazing_deg=args.grazing_deg,
                                                      min_views=args.min_views, progress=b)
    return capture, surface, mesh, info, coverage


def _write_coverage(out: Path, surface, coverage) -> None:
    """coverage.png: the texel grid, black off the atlas, red where no camera sees
    a texel (its maps are the fit's flagged defaults), grey levels by the number
    of cameras that see it."""
    from ..io import write_png

    cov = np.asarray(coverage.coverage)
    n = max(int(cov.max()), 1)
    img = np.zeros(cov.shape + (3,), np.uint8)
    seen = cov > 0
    level = np.round(64 + 191 * (cov.clip(0, None) / n)).astype(np.uint8)
    img[seen] = level[seen, None]
    img[cov == 0] = (255, 0, 0)
    write_png(out / "coverage.png", upscale_nearest(img))


def _report(fitted, surface, capture_dir: Path, times, normals: bool = False) -> dict:
    from ..io import is_map_set, read_maps
    from ..materials._maps import MODELS

    failed = np.asarray(fitted.failed)
    observed = np.asarray(fitted.observed)
    r = {
        "samples": int(surface.num_samples),
        "failed_fraction": float(np.mean(failed)),
        "residual_rms_median": float(np.median(np.asarray(fitted.residual)[~failed])) if (~failed).any() else None,
        # Over the samples with observations: a photo capture's unseen texels would otherwise decide them.
        "observed_samples": int(np.sum(observed > 0)),
        "steps_median": float(np.median(np.asarray(fitted.steps)[observed > 0])) if np.any(observed > 0) else 0.0,
        "observed_median": float(np.median(observed[observed > 0])) if np.any(observed > 0) else 0.0,
        "timings_s": {k: round(v, 3) for k, v in times.items()},
    }
    if getattr(fitted, "model", None) is not None:
        counts = np.bincount(np.asarray(fitted.model).reshape(-1), minlength=len(MODELS))
        r["model_counts"] = {m: int(c) for m, c in zip(MODELS, counts, strict=False)}
    if hasattr(fitted, "unresolved"):
        r["unresolved_fraction"] = float(np.mean(np.asarray(fitted.unresolved)))
    if hasattr(fitted, "ambiguous"):
        r["ambiguous_fraction"] = float(np.mean(np.asarray(fitted.ambiguous)))
    truth_dir = capture_dir / "truth"
    if is_map_set(truth_dir) and not (~failed).any():
        # Every texel flagged (e.g. a 12-light dome leaves fewer than 8 valid lights a texel): nothing to compare.
        r["against_truth"] = None
    elif is_map_set(truth_dir):
        truth, _ = read_maps(truth_dir)
        r["against_truth"] = _against_truth(fitted, truth.maps(surface), normals=normals)
    return r


# report.json's against_truth["errors"]: name -> (what it is, the texels it is over beyond "seen").
ERROR_ROWS = {
    "diffuse_albedo_rel": "diffuse albedo relative error, abs(fit - truth) / truth (R, G, B pooled)",
    "specular_albedo_rel": "specular albedo relative error (texels whose true rung has a lobe and rho_s > 0)",
    "roughness_rel": "roughness relative error (texels whose fitted and true rung both have a lobe)",
    "normal_deg": "shading normal angle to the truth's, degrees (--normals)",
}


def _stats(values: np.ndarray, where: np.ndarray) -> dict:
    """{"samples": texels counted, "median", "p95"} of ``values`` [P] or [P, C] at the texels ``where`` [P]
    (per-channel values pooled); None statistics over no texel."""
    v = np.asarray(values, np.float64)[np.asarray(where, bool)].reshape(-1)
    n = int(np.count_nonzero(where))
    if v.size == 0:
        return {"samples": n, "median": None, "p95": None}
    return {"samples": n, "median": float(np.median(v)), "p95": float(np.percentile(v, 95))}


def _against_truth(fitted, t, normals: bool = False) -> dict:
    """The fit against a simulated capture's truth/: each error over every seen texel (observations > 0,
    flagged ones included: what the maps hold there) and over the unflagged ones, with the texel counts.
    Roughness only where the fitted and the true rung both have a lobe (a Lambert texel's roughness is a
    placeholder); specular albedo where the truth has one; normals with ``--normals``. The flat keys
    (``*_median`` / ``*_p95``) are the unflagged rows', as before."""
    from ..materials._maps import LAMBERT

    seen = np.asarray(fitted.observed) > 0
    ok = seen & ~np.asarray(fitted.failed)
    rel = lambda a, b: np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64)) / np.maximum(  # noqa: E731
        np.abs(np.asarray(b, np.float64)), 1e-12)
    t_rho_s = np.asarray(t.rho_s, np.float64)[:, 0]
    lobe = (np.asarray(fitted.model) != LAMBERT) & (np.asarray(t.model) != LAMBERT)
    rows = {"diffuse_albedo_rel": (rel(fitted.rho_d, t.rho_d), np.ones_like(seen)),
            "specular_albedo_rel": (rel(fitted.rho_s, t.rho_s), (np.asarray(t.model) != LAMBERT) & (t_rho_s > 0)),
            "roughness_rel": (rel(np.asarray(fitted.alpha)[:, :1], np.asarray(t.alpha)[:, :1]), lobe)}
    if normals:
        rows["normal_deg"] = (_angular_error_deg(np.asarray(fitted.normal, np.float64),
                                                 np.asarray(t.normal, np.float64)), np.ones_like(seen))
    errors = {name: {"what": ERROR_ROWS[name], "all_seen": _stats(v, seen & m), "unflagged": _stats(v, ok & m)}
              for name, (v, m) in rows.items()}
    out = {"seen_samples": int(seen.sum()), "unflagged_samples": int(ok.sum())}
    for name, old in (("diffuse_albedo_rel", "diffuse_albedo_rel_error"), ("roughness_rel", "roughness_rel_error")):
        u = errors[name]["unflagged"]
        out[f"{old}_median"], out[f"{old}_p95"] = u["median"], u["p95"]
    out["errors"] = errors
    return out


def _g(x, unit: str = "") -> str:
    """A report number to 3 significant figures ("-" for None)."""
    return "-" if x is None else f"{x:.3g}{unit}"


def _truth_md(a: dict) -> list[str]:
    """report.md's table of the errors against truth/: every row over all seen texels and the unflagged ones."""
    lines = [f"Against the simulated truth, over the {a['seen_samples']} seen texels (flagged ones included: their "
             f"maps are what the fit wrote) and over the {a['unflagged_samples']} unflagged ones:", "",
             "| error | seen texels: median / 95th pct (texels) | unflagged: median / 95th pct (texels) |",
             "| --- | --- | --- |"]
    for row in a["errors"].values():
        cells = [f"{_g(c['median'])} / {_g(c['p95'])} ({c['samples']})" for c in (row["all_seen"], row["unflagged"])]
        lines.append(f"| {row['what']} | {cells[0]} | {cells[1]} |")
    return lines + [""]


def _report_md(r: dict) -> str:
    lines = ["# relight fit report", "",
             f"{r['samples']} texels fitted; {100 * r['failed_fraction']:.2f}% flagged (solver failure or fewer "
             f"than 8 valid lights). Median RMS residual {_g(r['residual_rms_median'])} (unflagged texels); over the "
             f"{r['observed_samples']} texels with observations, median steps {r['steps_median']:.0f} and median "
             f"valid observations {r['observed_median']:.0f}.", ""]
    if r.get("ambiguous_fraction"):
        lines += [f"{100 * r['ambiguous_fraction']:.2f}% of the texels are ambiguous (`Fit.ambiguous`: a diffuse "
                  "albedo 1-sigma above 10%; at low signal to noise a broad grey lobe can take part of the diffuse "
                  "term, so their albedo may read dark).", ""]
    if r.get("against_truth") is None and "against_truth" in r:
        lines += ["Every texel is flagged, so there is no comparison against the simulated truth.", ""]
    elif "against_truth" in r:
        lines += _truth_md(r["against_truth"])
    if "photos" in r:
        ph = r["photos"]
        lines += [f"Photo capture resampled onto the texel grid ({ph['sampling']}; views beyond "
                  f"{ph['grazing_deg']:g} degrees, outside a mask, occluded or saturated dropped): "
                  f"**{ph['unseen']} of {ph['texels']} texels ({100 * ph['unseen_fraction']:.1f}%) unseen** "
                  f"(seen by fewer than {ph['min_views']} camera(s); flagged, red in coverage.png).", "",
                  "| camera | texels seen | valid observations |", "| --- | --- | --- |",
                  *[f"| {v['camera']} | {v['seen']} | {100 * v['valid_fraction']:.1f}% |" for v in ph["views"]], ""]
    if "diligent" in r:
        dg = r["diligent"]
        lines += [f"DiLiGenT object {dg['object']}: {dg['pixels']} pixels (every {dg['subsample']}-th in x and y), "
                  f"{dg['lights']} lights; shading normals fitted (normals.png: 0.5 + 0.5 n, camera frame).", ""]
        if "normal_error_deg" in dg:
            e = dg["normal_error_deg"]
            lines += ["| angular error vs Normal_gt (deg) | mean | median |", "| --- | --- | --- |",
                      f"| relight fit | {e['mean']:.2f} | {e['median']:.2f} |",
                      f"| Lambertian least squares (baseline) | {e['lambert_ls_baseline_mean']:.2f} | "
                      f"{e['lambert_ls_baseline_median']:.2f} |", ""]
    if "subsurface" in r:
        lines += _subsurface_md(r["subsurface"])
    if "model_counts" in r:
        lines += ["Texels per model: " + ", ".join(f"{k} {v}" for k, v in r["model_counts"].items() if v) + ".", ""]
    lines += ["| stage | seconds |", "| --- | --- |",
              *[f"| {k[:-2]} | {v:.2f} |" for k, v in r["timings_s"].items()], ""]
    return "\n".join(lines)


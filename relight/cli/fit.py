"""``relight fit``: a texel-space capture (``relight.fitting.fit_resumable``, then with --subsurface
``subsurface_step``), a photo capture (``relight.io.photos_to_texels`` first) or a DiLiGenT object
(``relight.fitting.fit_diligent``) fitted and written with its report (``relight.fitting.write_fit_folder``).
docs/cli.md shows the same in Python."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

# stage, brdf, JAX and the rest of relight are imported inside the functions that use them, so that
# `relight fit --help` builds its parser without them.
from ._common import (
    INDEX_FRAMES,
    INDEX_SIZE,
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
    warn_mesh_size,
    write_index_page,
    write_settings,
)

# relight.fit's rungs (relight.MODELS up to subsurface, which the subsurface step fits afterwards) and the ladder,
# and its solvers (relight.SOLVERS): spelled here so that the parser needs no JAX; tests/relight/test_cli_ux.py
# checks them against the library's.
FIT_MODELS = ("lambert", "blinn_phong", "ggx", "ggx_aniso", "auto")
METHODS = ("lm", "optx-lm", "gn", "dogleg", "bfgs")
# --subsurface: off, or subsurface_step's per= (region: one mfp per region of --regions; texel: per texel; auto:
# the ladder none / region / texel by held-out error).
SUBSURFACE_MODES = ("off", "region", "texel", "auto")
# The parts folder of fit_resumable inside --out: hidden, it is not part of the map set.
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
    p.add_argument("--solver", default="lm", choices=METHODS,
                   help=f"least-squares solver: {', '.join(METHODS)} (default: lm, Levenberg-Marquardt)")
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
                        "the capture's metadata.subsurface.eta, else skin's, skin_bssrdf.SKIN_ETA)")
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


def run(args) -> int:
    from ..envmap import load_envmap
    from ..io import is_diligent_folder, is_photo_capture

    envmap = envmap_path(args.envmap)
    load_envmap(envmap)  # refuse a missing or corrupt map before the fit, not after
    kwargs = {"solver": args.solver, **({"model": args.model} if args.model else {}),
              **({"normals": True} if args.normals else {})}
    at_least("--block", args.block, 1)
    devices = parse_devices(args.devices)
    capture_dir = Path(args.capture)
    diligent = is_diligent_folder(capture_dir)
    photos = not diligent and is_photo_capture(capture_dir)
    _check_subsurface_flags(args, capture_dir, "diligent" if diligent else "photos" if photos else "texel")
    if diligent:
        return _run_diligent(args, capture_dir, kwargs, devices)
    if args.subsample != 1:
        raise CLIError("--subsample applies to DiLiGenT folders only")
    # Refused before the capture is read; output_set checks again with the folder locked.
    check_out(args.out, "fit", keep=(PARTS,))
    with output_set(args.out, "fit", args.quiet, keep=(PARTS,)) as tmp:
        return _run_texel(args, capture_dir, photos, kwargs, devices, envmap, Path(args.out), tmp)


def _fit(args, capture, surface, out: Path, kwargs: dict, devices, metadata: dict, times: dict):
    """The fit in resumable parts (out/.parts), then --subsurface's step: (Fit, parts entry, settings|None)."""
    from ..fitting import FitOptions, PartsFingerprintError, fit_resumable, subsurface_step
    from ..io import read_regions
    from ..results import commit_point

    t0 = time.perf_counter()
    with bar(surface.num_samples, "fit (texels)", args.quiet) as b:
        # commit_point("block"): the kill tests' named point (a no-op unless a test injects a hook).
        options = FitOptions(block=args.block, devices=devices, progress=b, on_block=lambda *_: commit_point("block"))
        try:
            fitted, parts = fit_resumable(capture, surface, out / PARTS, resume=args.resume, options=options,
                                          **kwargs)
        except PartsFingerprintError as err:
            raise CLIError(f"--resume: {out / PARTS} holds the parts of another fit (the capture, the surface or a "
                           f"setting such as --model, --solver, --normals, --block or --devices changed): rerun "
                           f"without --resume to fit afresh ({err})") from None
    times["fit_s"] = time.perf_counter() - t0
    if args.subsurface == "off":
        return fitted, parts, None
    t0 = time.perf_counter()
    regions = None if args.regions is None else read_regions(args.regions, surface)
    with bar(None, "fit subsurface", args.quiet) as b:
        fitted, sss = subsurface_step(capture, surface, fitted, per=args.subsurface, regions=regions, eta=args.eta,
                                      metadata=metadata, passes=args.passes, model=args.model or "ggx",
                                      normals=args.normals, solver=args.solver,
                                      options=FitOptions(block=args.block, devices=devices, progress=b))
    times["subsurface_s"] = time.perf_counter() - t0
    sss["eta_from"] = {"argument": "--eta"}.get(sss["eta_from"], sss["eta_from"])
    if regions is not None:
        sss["regions"]["file"] = str(Path(args.regions).resolve())
    return fitted, parts, sss


def _run_texel(args, capture_dir: Path, photos: bool, kwargs: dict, devices, envmap: Path, out: Path,
               tmp: Path) -> int:
    """A texel-space or photo capture fitted into the result set built at ``tmp`` (``out`` once swapped)."""
    import stage

    from ..fitting import read_truth, write_fit_folder

    t0, times, metadata, coverage = time.perf_counter(), {}, {}, None
    if photos:
        capture, surface, mesh, info, coverage = _ingest_photos(args, capture_dir)
    else:
        capture, surface, mesh, metadata = _read_texel(args, capture_dir)
        info = metadata["surface"]
    times["read_s"] = time.perf_counter() - t0
    out.mkdir(parents=True, exist_ok=True)  # for out/.parts; the set itself is built in tmp
    fitted, parts, sss = _fit(args, capture, surface, out, kwargs, devices, metadata, times)
    meta = {"capture": str(capture_dir.resolve()), "fit_options": kwargs, "source": "relight fit"}
    report, scene = write_fit_folder(tmp, fitted, surface, cameras=capture.cameras, rig=capture.rig, mesh=mesh,
                                     surface_info=info, metadata=meta, envmap=envmap, normals=args.normals,
                                     truth=read_truth(capture_dir, surface), subsurface=sss, coverage=coverage,
                                     timings=times, extra={"parts": parts})
    write_settings(tmp, "fit", args, capture=str(capture_dir.resolve()), envmap=str(envmap), fit_options=kwargs,
                   mesh=info, samples=surface.num_samples, input="photos" if photos else "texel", subsurface=sss,
                   mitsuba_scene=None if scene is None else str(out / scene.relative_to(tmp)), block=args.block,
                   devices=parts["devices"], parts=str(out / PARTS), streamed=not isinstance(capture, stage.Capture))
    if not args.no_index:
        write_index_page(tmp, lambda: _index_sweeps(tmp, photos, envmap, fitted, surface, mesh, capture), "fit",
                         args.quiet, location=out)
    if report["failed_fraction"] >= 0.5:
        print(f"relight fit: warning: {100 * report['failed_fraction']:.0f}% of the texels are flagged (a solver "
              "failure, or fewer than 8 valid lights: a rig with more lights, or more cameras, covers them); their "
              "maps hold the defaults", file=sys.stderr)
    if summary(args):
        tail = ""
        if sss is not None:
            ss, med = report["subsurface"], report["subsurface"]["mfp_median_mm"]
            tail = (f"; subsurface ({args.subsurface}) on {ss['subsurface_samples']} texels" +
                    ("" if med is None else ", median mfp " + "/".join(f"{x:.3g}" for x in med) + " mm (R/G/B)"))
        resumed = f"; {parts['resumed_blocks']} of {parts['blocks']} blocks resumed" * bool(parts["resumed_blocks"])
        print(f"wrote {out}/ (texture set, scene.xml, report.md); {report['samples']} texels, "
              f"{100 * report['failed_fraction']:.1f}% flagged{tail}{resumed}")
    return 0


def _index_sweeps(tmp: Path, photos: bool, envmap: Path, fitted, surface, mesh, capture):
    """index.html's slider: the capture the maps were fitted from, relit image-based (read back whole if small
    enough: ``relight.view.folder_sweeps``); without one (a photo capture, a large one), the fitted maps
    rendered model-based through the capture's rig."""
    from ..envmap import load_envmap
    from ..view import folder_sweeps, maps_sweep

    rows, note = ([], None) if photos else folder_sweeps(tmp, envmap, INDEX_FRAMES, INDEX_SIZE, model=False)
    if rows:
        return rows, note
    return [maps_sweep(fitted.maps(surface), surface, mesh, capture.cameras[0], load_envmap(envmap), rig=capture.rig,
                       frames=INDEX_FRAMES, size=INDEX_SIZE,
                       label="the fitted maps rendered model-based (the capture's rig)")], None


def _read_texel(args, capture_dir: Path):
    """A texel-space capture folder or store: opened lazily (``open_texel_capture``: the mask is read
    to find the seen texels, the radiance block by block later), or, with --subsurface, loaded whole."""
    from ..io import load_texel_capture, open_texel_capture

    _refuse_photo_flags(args, f"{capture_dir} is a texel-space capture, which records its mesh and rig "
                              "(they apply to photo captures)")
    if args.subsurface != "off":
        # The subsurface fit couples texels through the diffusion operator: it takes the capture whole.
        with bar(None, "read capture (images)", args.quiet, waiting="reading") as b:
            return load_texel_capture(capture_dir, progress=b)
    with bar(None, "read mask", args.quiet, waiting="reading") as b:
        return open_texel_capture(capture_dir, progress=b)


def _check_subsurface_flags(args, capture_dir: Path, kind: str) -> None:
    """CLIError on --subsurface / --regions / --eta / --passes that do not go together or with this kind of
    input (subsurface fitting takes texel-space captures)."""
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


def _refuse_photo_flags(args, why: str) -> None:
    """CLIError when a flag that only photo captures take was given."""
    given = [f for f, v in (("--mesh", args.mesh), ("--units", args.units), ("--scale", args.scale),
                            ("--center", args.center), ("--rig-units", args.rig_units), ("--rig-up", args.rig_up))
             if v is not None]
    if given:
        raise CLIError(f"{' / '.join(given)}: {why}")


def _ingest_photos(args, capture_dir: Path):
    """A photo capture resampled onto ``--mesh``'s texel grid: (capture, surface, mesh, mesh spec,
    PhotoTexelReport)."""
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


def _run_diligent(args, folder: Path, kwargs: dict, devices) -> int:
    """``relight fit DILIGENT_DIR``: ``relight.fitting.fit_diligent`` and ``write_diligent_folder``."""
    from ..fitting import DILIGENT_MODEL, FitOptions, fit_diligent, write_diligent_folder
    from ..io import read_diligent

    _refuse_photo_flags(args, f"{folder} is a DiLiGenT folder (one orthographic view, calibrated light directions)")
    if args.resume:
        raise CLIError(f"--resume: {folder} is a DiLiGenT folder, fitted in one go (no parts)")
    at_least("--subsample", args.subsample, 1)
    t0, times = time.perf_counter(), {}
    d = read_diligent(folder)
    times["read_s"] = time.perf_counter() - t0
    check_out(args.out, "fit")
    out = Path(args.out)
    with output_set(args.out, "fit", args.quiet) as tmp:
        t0 = time.perf_counter()
        with bar(None, "fit (pixels)", args.quiet) as b:
            options = FitOptions(block=args.block, devices=devices, progress=b)
            fitted, surface, entry = fit_diligent(d, name=folder.name, subsample=args.subsample, options=options,
                                                  **kwargs)
        times["fit_s"] = time.perf_counter() - t0
        write_diligent_folder(tmp, fitted, surface, d.mask, entry, times)
        write_settings(tmp, "fit", args, capture=str(folder.resolve()), input="diligent", samples=surface.num_samples,
                       fit_options={"model": DILIGENT_MODEL, **kwargs, "normals": True, "block": args.block,
                                    "devices": devices})
        if not args.no_index:
            write_index_page(tmp, lambda: ([], "no rotation slider: a DiLiGenT object is lit by its calibrated "
                                               "directional lights only (no rig to relight an environment with)"),
                             "fit", args.quiet, location=out)
    if summary(args):
        e = entry.get("normal_error_deg")
        tail = "" if e is None else f"; mean normal error {e['mean']:.2f} deg"
        print(f"wrote {out}/ (normals, albedo, report.md); {surface.num_samples} pixels{tail}")
    return 0

"""``relight fit``: a texel-space capture, a store or a photo capture fitted and written with its report
(``relight.fitting.fit_folder``), or a DiLiGenT object (``relight.fitting.fit_diligent_folder``); this module
checks the flags, makes that one call and prints. docs/cli.md shows the same in Python."""

from __future__ import annotations

import sys
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
    add_out,
    add_photo_texel_flags,
    at_least,
    bar,
    check_out,
    envmap_path,
    finish_parser,
    output_set,
    photo_mesh_from_args,
    refuse_photo_flags,
    summary,
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
    add_photo_texel_flags(p, "photo captures")
    p.add_argument("--subsample", type=int, default=1,
                   help="DiLiGenT folders: fit every k-th pixel in x and y (quick looks; default 1: all)")
    add_out(p, "output folder for the map set")
    p.add_argument("--solver", default="lm", choices=METHODS,
                   help=f"least-squares solver: {', '.join(METHODS)} (default: lm, Levenberg-Marquardt)")
    p.add_argument("--model", default=None, choices=FIT_MODELS,
                   help="reflectance model: a rung of the ladder or auto (per-texel selection on the pooled "
                        "held-out and training prediction error); default: relight.fit's own (auto)")
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
    at_least("--block", args.block, 1)
    devices = parse_devices(args.devices)
    capture_dir = Path(args.capture)
    diligent = is_diligent_folder(capture_dir)
    photos = not diligent and is_photo_capture(capture_dir)
    _check_subsurface_flags(args, capture_dir, "diligent" if diligent else "photos" if photos else "texel")
    if diligent:
        return _run_diligent(args, capture_dir, devices)
    if args.subsample != 1:
        raise CLIError("--subsample applies to DiLiGenT folders only")
    if not photos:
        refuse_photo_flags(args, f"{capture_dir} is a texel-space capture, which records its mesh and rig (they "
                                  "apply to photo captures)")
    mesh = photo_mesh_from_args(args, capture_dir) if photos else None
    # Refused before the capture is read; output_set checks again with the folder locked.
    check_out(args.out, "fit", keep=(PARTS,))
    with output_set(args.out, "fit", args.quiet, keep=(PARTS,)) as tmp:
        return _run_texel(args, capture_dir, mesh, devices, envmap, Path(args.out), tmp)


class _Bars:
    """The progress callback of the fit: the reading phases ("read mask", "read capture") on a bar that says
    "reading" until its first unit, the others on one that says "compiling"; a bar closes when the other kind
    starts."""

    def __init__(self, quiet):
        self.quiet, self.bars = quiet, {}

    def __call__(self, phase: str, done: int, total) -> None:
        kind = "reading" if str(phase).startswith("read") else "compiling"
        for other in [k for k in self.bars if k != kind]:
            self.bars.pop(other).close()
        if kind not in self.bars:
            self.bars[kind] = bar(total, phase, self.quiet, waiting=kind)
        self.bars[kind](phase, done, total)

    def __enter__(self) -> _Bars:
        return self

    def __exit__(self, *exc) -> None:
        for b in self.bars.values():
            b.close()


def _run_texel(args, capture_dir: Path, mesh, devices, envmap: Path, out: Path, tmp: Path) -> int:
    """A texel-space or photo capture fitted into the result set built at ``tmp`` (``out`` once swapped)."""
    from ..fitting import FitOptions, PartsFingerprintError, fit_folder
    from ..results import commit_point

    out.mkdir(parents=True, exist_ok=True)  # for out/.parts; the set itself is built in tmp
    with _Bars(args.quiet) as b:
        # commit_point("block"): the kill tests' named point (a no-op unless a test injects a hook).
        options = FitOptions(block=args.block, devices=devices, progress=b, on_block=lambda *_: commit_point("block"))
        try:
            r = fit_folder(capture_dir, tmp, parts=out / PARTS, model=args.model, normals=args.normals,
                           solver=args.solver, subsurface=None if args.subsurface == "off" else args.subsurface,
                           regions=args.regions, eta=args.eta, eta_from="--eta", passes=args.passes,
                           resume=args.resume, options=options, resolution=args.resolution,
                           grazing_deg=args.grazing_deg, min_views=args.min_views, rig_units=args.rig_units,
                           rig_up=args.rig_up, envmap=envmap, **({} if mesh is None else mesh))
        except PartsFingerprintError as err:
            raise CLIError(f"--resume: {out / PARTS} holds the parts of another fit (the capture, the surface or a "
                           f"setting such as --model, --solver, --normals, --block or --devices changed): rerun "
                           f"without --resume to fit afresh ({err})") from None
    report, parts, sss = r.report, r.parts, r.subsurface
    write_settings(tmp, "fit", args, capture=str(capture_dir.resolve()), envmap=str(envmap), fit_options=r.fit_options,
                   mesh=r.surface_info, samples=r.surface.num_samples, input=r.kind, subsurface=sss,
                   mitsuba_scene=None if r.scene is None else str(out / r.scene.relative_to(tmp)), block=args.block,
                   devices=parts["devices"], parts=str(out / PARTS), streamed=r.streamed)
    if not args.no_index:
        write_index_page(tmp, lambda: _index_sweeps(tmp, r, envmap), "fit", args.quiet, location=out)
    for w in r.warnings:
        print(f"relight fit: warning: {w}", file=sys.stderr)
    if summary(args):
        tail = ""
        if sss is not None:
            ss, med = report["subsurface"], report["subsurface"]["mfp_median_mm"]
            tail = (f"; subsurface ({args.subsurface}) on {ss['subsurface_samples']} texels" +
                    ("" if med is None else ", median mfp " + "/".join(f"{x:.3g}" for x in med) + " mm (R/G/B)"))
        resumed = f"; {parts['resumed_blocks']} of {parts['blocks']} blocks resumed" * bool(parts["resumed_blocks"])
        print(f"wrote {out}/ (texture set, scene.xml, report.md); {report['samples']} texels, "
              f"{100 * report['failed_fraction']:.1f}% flagged ({report['unseen_samples']} unseen, "
              f"{report['failed_seen_samples']} of {report['seen_samples']} seen failed){tail}{resumed}")
    return 0


def _index_sweeps(tmp: Path, r, envmap: Path):
    """index.html's slider, two rows at one exposure: the capture the maps were fitted from, relit image-based
    (read back whole if small enough: ``relight.view.folder_sweeps``; none for a photo capture or a large one),
    the reference, and the fitted maps rendered model-based through the capture's rig, what the fit made
    (``r``: the ``relight.fitting.FitFolderResult``)."""
    from ..envmap import load_envmap
    from ..view import folder_sweeps, maps_sweep

    rows, _ = ([], None) if r.kind == "photos" else folder_sweeps(tmp, envmap, INDEX_FRAMES, INDEX_SIZE,
                                                                  model=False)
    fitted = maps_sweep(r.fit.maps(r.surface), r.surface, r.mesh, r.capture.cameras[0], load_envmap(envmap),
                        rig=r.capture.rig, frames=INDEX_FRAMES, size=INDEX_SIZE,
                        label="the fitted maps rendered model-based (the capture's rig)",
                        exposure=rows[0].exposure if rows else None)
    return [*rows, fitted], None


def _check_subsurface_flags(args, capture_dir: Path, kind: str) -> None:
    """CLIError on --subsurface / --regions / --eta / --passes that do not go together or with this kind of
    input (subsurface fitting takes texel-space captures)."""
    at_least("--passes", args.passes, 1)
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


def _run_diligent(args, folder: Path, devices) -> int:
    """``relight fit DILIGENT_DIR``: ``relight.fitting.fit_diligent_folder``."""
    from ..fitting import DILIGENT_MODEL, FitOptions, fit_diligent_folder

    refuse_photo_flags(args, f"{folder} is a DiLiGenT folder (one orthographic view, calibrated light directions)")
    if args.resume:
        raise CLIError(f"--resume: {folder} is a DiLiGenT folder, fitted in one go (no parts)")
    at_least("--subsample", args.subsample, 1)
    check_out(args.out, "fit")
    out = Path(args.out)
    with output_set(args.out, "fit", args.quiet) as tmp:
        with _Bars(args.quiet) as b:
            r = fit_diligent_folder(folder, tmp, model=args.model, normals=args.normals, solver=args.solver,
                                    subsample=args.subsample,
                                    options=FitOptions(block=args.block, devices=devices, progress=b))
        write_settings(tmp, "fit", args, capture=str(folder.resolve()), input="diligent",
                       samples=r.surface.num_samples, fit_options={"model": DILIGENT_MODEL, **r.fit_options,
                                                                   "normals": True, "block": args.block,
                                                                   "devices": devices})
        if not args.no_index:
            write_index_page(tmp, lambda: ([], "no rotation slider: a DiLiGenT object is lit by its calibrated "
                                               "directional lights only (no rig to relight an environment with)"),
                             "fit", args.quiet, location=out)
    if summary(args):
        e = r.report["diligent"].get("normal_error_deg")
        tail = "" if e is None else f"; mean normal error {e['mean']:.2f} deg"
        print(f"wrote {out}/ (normals, albedo, report.md); {r.surface.num_samples} pixels{tail}")
    return 0

"""``relight simulate``: an OLAT capture of a mesh with the demo's skin-like
ground-truth material, written as a texel-space capture folder (``--space
texel``), a chunked capture store (``--out NAME.zarr``, streamed block by block)
or a camera-space photo capture (``--space image``: docs/capture_layout.md).

The command reads its flags and makes one library call:
``relight.simulation.simulate_texel_capture`` (``stage.simulate_into`` with keyed
sensor noise into a ``relight.io.CaptureFolderWriter`` or ``CaptureStoreWriter``,
and the truth) or ``relight.simulation.simulate_photo_capture``
(``stage.simulate_images``);
docs/cli.md shows the same from Python."""

from __future__ import annotations

import contextlib
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

# brdf, skin_bssrdf, stage and the rest of relight are imported on first use (the module's __getattr__ gives
# the names below), so that `relight simulate --help` builds its parser without JAX, as the other commands do.
from ._common import (
    INDEX_FRAMES,
    INDEX_SIZE,
    MIN_IMAGE_SIZE,
    CLIError,
    add_image_size,
    add_index_flag,
    add_mesh_flags,
    add_out,
    add_rig_file_flags,
    at_least,
    bar,
    check_out,
    finish_parser,
    mesh_from_args,
    output_set,
    parse_cameras,
    parse_rig,
    preset_mean_free_path,
    summary,
    warn_mesh_size,
    write_index_page,
    write_settings,
    writing,
)

if TYPE_CHECKING:  # what _LAZY imports at run time, spelled for readers and linters
    import skin_bssrdf
    import stage

    from ..io import open_capture_store, read_mean_free_path, spec_mesh
    from ..simulation import MeanFreePath, simulate_photo_capture, simulate_texel_capture

# The library names this module uses, imported on first use: name -> (module, attribute). A name a test or
# script has replaced (``relight.cli.simulate.spec_mesh = ...``) is kept.
_LAZY = {
    "skin_bssrdf": ("skin_bssrdf", None), "stage": ("stage", None),
    **{n: ("relight.io", n) for n in ("open_capture_store", "read_mean_free_path", "spec_mesh")},
    **{n: ("relight.simulation", n) for n in ("MeanFreePath", "simulate_photo_capture", "simulate_texel_capture")},
}

# relight.cli._common.SUBSURFACE_PRESETS (the --subsurface presets, read from skin_bssrdf), spelled here for the
# help text so that building the parser needs no JAX; tests/relight/test_cli_ux.py checks it against _common's.
_PRESET_NAMES = ("apple", "chicken1", "chicken2", "cream", "ketchup", "marble", "potato", "skimmilk", "skin1", "skin2",
                 "wholemilk")


def _load() -> None:
    """Import the library names of ``_LAZY`` into this module's globals (those not already set)."""
    for name in _LAZY:
        if name not in globals():
            __getattr__(name)


def __getattr__(name: str):
    import importlib

    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    module, attr = _LAZY[name]
    value = importlib.import_module(module)
    value = globals()[name] = value if attr is None else getattr(value, attr)
    return value


def add_parser(sub) -> None:
    p = sub.add_parser("simulate", help="simulate an OLAT capture of a mesh (texel space) into a capture folder",
                       description="Simulate a one-light-at-a-time capture of the demo's skin-like material on a "
                                   "mesh, in texel space, and write a capture folder that `relight fit` reads.")
    add_mesh_flags(p)
    p.add_argument("--rig", default="lsx", help="lsx | dome:N | rig.json (default: lsx, ICT Light Stage X)")
    add_rig_file_flags(p)
    p.add_argument("--resolution", type=int, default=64, help="texel grid size N (N x N; default: 64)")
    p.add_argument("--camera", default="front", help="front | cameras.json (default: front)")
    add_image_size(p)
    p.add_argument("--noise", default="none",
                   help="none | EXPOSURE: Poisson shot noise at EXPOSURE photo-electrons per unit radiance "
                        "(default: none)")
    p.add_argument("--read-noise", type=float, default=0.0, help="Gaussian read noise in electrons (with --noise)")
    p.add_argument("--seed", type=int, default=0, help="noise seed (default: 0)")
    p.add_argument("--half", action="store_true", help="store radiance as half floats")
    p.add_argument("--format", default="exr", choices=("exr", "png"), dest="image_format",
                   help="photographs of --space image: exr (float radiance; default) | png (16-bit counts of the "
                        "--noise sensor, counts = EXPOSURE x radiance clipped at 65535, as a camera delivers them)")
    p.add_argument("--space", default="texel", choices=("texel", "image"),
                   help="texel: a texel-space capture folder (default; what `relight fit` reads) | image: a "
                        "camera-space photo capture, one image per camera and light (what a real stage delivers; "
                        "`relight render` relights it)")
    p.add_argument("--subsurface", default=None, metavar="PRESET|MAP",
                   help="subsurface scattering instead of the local diffuse term (texel space only): a measured "
                        f"material of Jensen et al. 2001 ({', '.join(_PRESET_NAMES)}) giving the diffuse mean "
                        "free path per channel (and eta), or an EXR of the mean free path in mm on the texel grid "
                        "(R, G, B or Y; resampled if another size; 0 = no subsurface at that texel). The albedo "
                        "stays the demo's diffuse albedo map (default: none)")
    p.add_argument("--mfp-scale", type=float, default=1.0,
                   help="multiply the mean free path of --subsurface by this factor (default: 1)")
    p.add_argument("--eta", type=float, default=None,
                   help="relative index of refraction of the subsurface Fresnel transmittances (default: the "
                        "preset's, 1.4 for a map)")
    p.add_argument("--block", type=int, default=None, metavar="N",
                   help=f"texels of the grid per block when --out ends in {STORE_SUFFIX} (the capture is "
                        f"streamed into a capture store block by block; default {DEFAULT_BLOCK}; rounded down to a "
                        "multiple of the store's sample chunk). Peak memory grows with it, not with --resolution")
    add_out(p, f"capture folder to write, or a capture store if the name ends in {STORE_SUFFIX}")
    add_index_flag(p)
    finish_parser(p, run)


# --out NAME.zarr: a capture store (relight convert's rule).
STORE_SUFFIX = ".zarr"
# stage.DEFAULT_BLOCK (grid texels per block of the store form), spelled here for the help text (no JAX);
# tests/relight/test_cli_simulate_store.py checks it against stage's.
DEFAULT_BLOCK = 1 << 14


def _mfp_source(args):
    """``relight.simulation.MeanFreePath`` of --subsurface / --mfp-scale / --eta (a preset's per-channel mean free
    path [3] or a map [H, W, 3]), or None without --subsurface."""
    if args.subsurface is None:
        if args.mfp_scale != 1.0 or args.eta is not None:
            raise CLIError(f"{'--mfp-scale' if args.mfp_scale != 1.0 else '--eta'}: needs --subsurface PRESET|MAP")
        return None
    if not (np.isfinite(args.mfp_scale) and args.mfp_scale > 0):
        raise CLIError(f"--mfp-scale {args.mfp_scale}: must be a finite number > 0")
    if args.eta is not None and not (np.isfinite(args.eta) and 1.0 < args.eta <= 3.0):
        raise CLIError(f"--eta {args.eta}: must be in (1, 3]")
    path = Path(args.subsurface)
    if not (path.is_file() or path.suffix.lower() == ".exr"):
        mfp, eta = preset_mean_free_path(args.subsurface)
        return MeanFreePath(mfp * args.mfp_scale, eta if args.eta is None else args.eta, f"preset {args.subsurface}",
                            args.mfp_scale)
    try:
        mfp = read_mean_free_path(path)
    except (OSError, ValueError) as err:
        raise CLIError(f"--subsurface {err}") from None
    return MeanFreePath(mfp * args.mfp_scale, skin_bssrdf.SKIN_ETA if args.eta is None else args.eta, str(path),
                        args.mfp_scale)


def _noise(spec: str, read_noise: float):
    if spec.lower() == "none":
        if read_noise:
            raise CLIError("--read-noise needs --noise EXPOSURE")
        return None
    try:
        exposure = float(spec)
    except ValueError:
        raise CLIError(f"--noise {spec}: expected 'none' or a positive exposure "
                       "(electrons per unit radiance)") from None
    if not exposure > 0 or not np.isfinite(exposure):
        raise CLIError(f"--noise {spec}: the exposure must be a positive number")
    if read_noise < 0:
        raise CLIError(f"--read-noise {read_noise}: must be >= 0")
    return stage.Sensor(exposure=exposure, read_noise=read_noise, shot_noise=True)


def _noise_meta(args, sensor, sample: str) -> dict | None:
    return None if sensor is None else {"model": "poisson-gaussian", "exposure": float(args.noise),
                                        "read_noise": args.read_noise, "seed": args.seed,
                                        "keys": f"fold_in(fold_in(fold_in(PRNGKey(seed), view), light), {sample})"}


def _check_form(args, out: Path) -> bool:
    """True for the store form (``--out`` ending in .zarr); CLIError naming the flag for a combination that
    contradicts the form."""
    store = out.suffix == STORE_SUFFIX
    if store and args.space == "image":
        raise CLIError(f"--out {out}: a capture store ({STORE_SUFFIX}) holds texel-space captures; --space image "
                       f"writes a photo capture folder (give a name not ending in {STORE_SUFFIX})")
    if args.image_format == "png" and args.space != "image":
        raise CLIError("--format png: photographs only (--space image); a texel capture holds float radiance")
    if args.image_format == "png" and args.noise.lower() == "none":
        raise CLIError("--format png: 16-bit PNGs hold a sensor's counts; give the sensor with --noise EXPOSURE "
                       "(photo-electrons per unit radiance; counts = EXPOSURE x radiance, clipped at 65535)")
    if args.image_format == "png" and args.half:
        raise CLIError("--half: applies to EXR photographs, not --format png")
    if args.block is not None and not store:
        raise CLIError(f"--block {args.block}: applies to a capture store only (--out ending in {STORE_SUFFIX}); "
                       "a capture folder is simulated in memory")
    if args.block is not None and args.subsurface is not None:
        raise CLIError(f"--block {args.block}: --subsurface couples every texel through the diffusion operator, "
                       "so the store is written one light chunk of the whole surface at a time, not in blocks")
    if args.block is not None:
        at_least("--block", args.block, 64)
    check_out(out, "simulate", legacy=_legacy(args, store))
    return store


def _legacy(args, store: bool):
    """What an earlier simulate wrote before result-set manifests (a finished capture store, a capture
    folder, a photo capture), which this one may replace; anything else non-empty is refused."""
    if store:
        def finished_store(p: Path) -> bool:
            try:
                open_capture_store(p)
                return True
            except (OSError, ValueError):
                return False

        return finished_store
    if args.space == "image":
        from ..io import is_photo_capture

        return is_photo_capture
    return lambda p: (p / "capture.json").is_file()


def run(args) -> int:
    _load()
    at_least("--resolution", args.resolution, 2)
    at_least("--image-size", args.image_size, MIN_IMAGE_SIZE)
    out = Path(args.out)
    sensor = _noise(args.noise, args.read_noise)
    sss = _mfp_source(args)
    if sss is not None and args.space == "image":
        raise CLIError(f"--subsurface {args.subsurface}: texel space only (--space texel): the diffusion operator "
                       "couples texels over the whole surface, which a camera-space capture does not sample")
    store = _check_form(args, out)
    unhashed = ("zarr.json", "radiance/", "mask/") if store else ()  # a store's chunks: its own manifest's
    # The folder is locked from here to the swap: a second simulate into it fails at once.
    with output_set(out, "simulate", args.quiet, create=False, unhashed=unhashed, legacy=_legacy(args, store)) as tmp:
        t0 = time.perf_counter()
        spec = mesh_from_args(args)
        mesh = spec_mesh(spec, str(spec["path"]))
        rig, rig_desc = parse_rig(args.rig, args.rig_units, args.rig_up)
        warn_mesh_size("simulate", mesh, rig)
        cams = parse_cameras(args.camera, mesh, args.image_size)
        geometry_s = time.perf_counter() - t0
        with writing(out), bar(None, "simulate", args.quiet) as b, _flag_errors(args):
            if args.space == "image":
                done = simulate_photo_capture(tmp, mesh, rig, cams, mesh_info=spec, rig_info=rig_desc,
                                              half=args.half, sensor=sensor, seed=args.seed,
                                              fmt=args.image_format, progress=b,
                                              metadata={"noise": _noise_meta(args, sensor, "pixel"),
                                                        "writer": "relight simulate --space image"})
            else:
                done = simulate_texel_capture(tmp, mesh, args.resolution, rig, cams, surface_info=spec,
                                              rig_info=rig_desc, store=store, half=args.half, sensor=sensor,
                                              block=DEFAULT_BLOCK if args.block is None else args.block,
                                              seed=args.seed, subsurface=sss, progress=b,
                                              metadata={"noise": _noise_meta(args, sensor, "texel"),
                                                        "writer": "relight simulate"})
        times = dict(done.resolved["timings_s"])  # with the seconds spent here reading the mesh, rig and cameras
        times = {"geometry_s": round(geometry_s + times.pop("geometry_s", 0.0), 3), **times}
        write_settings(tmp, "simulate", args, **{**done.resolved, "timings_s": times})
        if not args.no_index:
            write_index_page(tmp, lambda: _sweeps(tmp, done, rig), "simulate", args.quiet, location=out)
    if summary(args):
        print(f"wrote {out}{'' if store else '/'} {done.summary}")
    return 0


def _sweeps(tmp: Path, done, rig):
    """index.html's slider: camera 0's photographs, or the capture read back whole, relit image-based under
    the bundled map (``relight.view``), unless it is too large for that (the page then says so)."""
    from ..envmap import bundled_envmap_path, load_envmap
    from ..view import folder_sweeps, photo_sweep

    if done.images is None:
        return folder_sweeps(tmp, None, INDEX_FRAMES, INDEX_SIZE)
    return [photo_sweep(done.images[0], done.masks[0], rig, load_envmap(bundled_envmap_path()), INDEX_FRAMES,
                        "camera 0's photographs relit image-based (bundled map)")], None


@contextlib.contextmanager
def _flag_errors(args):
    """The library's ValueErrors that name an argument ("cameras: ...", "camera 2: ...", "mean_free_path:
    ..."), as CLIErrors naming the flag."""
    flags = {"cameras": f"--camera {args.camera}", "camera": f"--camera {args.camera}: camera",
             "mean_free_path": f"--subsurface {args.subsurface}"}
    try:
        yield
    except ValueError as err:
        head = str(err).split(":", 1)[0].split(" ", 1)[0]
        if head not in flags:
            raise
        raise CLIError(f"{flags[head]}{str(err)[len(head):]}") from None

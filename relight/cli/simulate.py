"""``relight simulate``: an OLAT capture of a mesh with the demo's skin-like
ground-truth material, written as a texel-space capture folder (``--space
texel``), a chunked capture store (``--out NAME.zarr``, streamed block by block)
or a camera-space photo capture (``--space image``: docs/capture_layout.md).

The command parses its flags and calls the library: ``stage.simulate_into``
(texel space: the streaming simulator with keyed sensor noise, into a
``relight.io.CaptureFolderWriter`` or ``relight.io.CaptureStoreWriter``),
``stage.subsurface_from_maps`` (``--subsurface``) and ``stage.simulate_images``
(``--space image``); docs/cli.md shows the same from Python. Sensor noise
follows ``stage.observation_key``: each observation's noise is a function of
(seed, view, light, texel or pixel) only."""

from __future__ import annotations

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
    demo_material,
    finish_parser,
    mesh_from_args,
    output_set,
    parse_cameras,
    parse_rig,
    preset_mean_free_path,
    summary,
    warn_mesh_size,
    write_index_page,
    write_map_previews,
    write_preview,
    write_settings,
    writing,
)

if TYPE_CHECKING:  # what _LAZY imports at run time, spelled for readers and linters
    import brdf
    import skin_bssrdf
    import stage

    from ..image import dilate, texture_view
    from ..io import (
        CaptureFolderWriter,
        CaptureStoreWriter,
        mean_free_path_at,
        open_capture_store,
        read_mean_free_path,
        spec_mesh,
        store_blocks,
        texel_surface,
        write_exr,
        write_maps,
        write_photo_capture,
    )
    from ..materials import GGX, SUBSURFACE, material_maps
    from ..results import open_result_set

# The library names this module uses, imported on first use: name -> (module, attribute). A name a test or
# script has replaced (``relight.cli.simulate.texel_surface = ...``) is kept.
_LAZY = {
    "brdf": ("brdf", None), "skin_bssrdf": ("skin_bssrdf", None), "stage": ("stage", None),
    **{n: ("relight.image", n) for n in ("dilate", "texture_view")},
    **{n: ("relight.io", n) for n in ("CaptureFolderWriter", "CaptureStoreWriter", "mean_free_path_at",
                                      "open_capture_store", "read_mean_free_path", "spec_mesh", "store_blocks",
                                      "texel_surface", "write_exr", "write_maps", "write_photo_capture")},
    **{n: ("relight.materials", n) for n in ("GGX", "SUBSURFACE", "material_maps")},
    "open_result_set": ("relight.results", "open_result_set"),
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
# Lights per chunk: the store form two store chunks' worth (relight.io's LIGHT_CHUNK = 8; with --subsurface
# one), so every write completes its store chunks; the folder form stage.simulate's default.
_STORE_LIGHT_CHUNK, _SSS_STORE_LIGHT_CHUNK, _FOLDER_LIGHT_CHUNK = 16, 8, 64
# Texels per call of the camera visibility pass (stage.camera_visibility's chunk).
_CAMERA_CHUNK = 1 << 16


def _mfp_source(args):
    """(kind, the preset's per-channel mfp [3] or the map [H, W, 3], eta) of
    --subsurface / --mfp-scale / --eta, or None without --subsurface."""
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
        return "preset", mfp * args.mfp_scale, eta if args.eta is None else args.eta
    try:
        mfp = read_mean_free_path(path)
    except (OSError, ValueError) as err:
        raise CLIError(f"--subsurface {err}") from None
    return "map", mfp * args.mfp_scale, skin_bssrdf.SKIN_ETA if args.eta is None else args.eta


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


def _memory() -> float | None:
    """The process's peak resident set so far (MiB), then freed heap handed back to the system (glibc's
    ``malloc_trim``: the grid's temporaries would otherwise stay resident under the phases that follow)."""
    try:
        import ctypes
        import resource

        peak = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1)  # Linux: KiB
        ctypes.CDLL("libc.so.6").malloc_trim(0)
        return peak
    except (ImportError, OSError, AttributeError):  # pragma: no cover - not Linux
        return None


def _check_form(args, out: Path) -> bool:
    """True for the store form (``--out`` ending in .zarr); CLIError naming the flag for a combination that
    contradicts the form."""
    store = out.suffix == STORE_SUFFIX
    if store and args.space == "image":
        raise CLIError(f"--out {out}: a capture store ({STORE_SUFFIX}) holds texel-space captures; --space image "
                       f"writes a photo capture folder (give a name not ending in {STORE_SUFFIX})")
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
    sss_source = _mfp_source(args)
    if sss_source is not None and args.space == "image":
        raise CLIError(f"--subsurface {args.subsurface}: texel space only (--space texel): the diffusion operator "
                       "couples texels over the whole surface, which a camera-space capture does not sample")
    store = _check_form(args, out)
    unhashed = ("zarr.json", "radiance/", "mask/") if store else ()  # a store's chunks: its own manifest's
    # The folder is locked from here to the swap: a second simulate into it fails at once.
    with output_set(out, "simulate", args.quiet, create=False, unhashed=unhashed, legacy=_legacy(args, store)) as tmp:
        if args.space == "image":
            return _run_image(args, out, sensor, tmp)
        return _run_texel(args, out, sensor, sss_source, tmp, store)


def _run_texel(args, out: Path, sensor, sss_source, tmp: Path, store: bool) -> int:
    """Texel space: ``stage.simulate_into`` a capture folder (held in memory, written whole) or a capture
    store (streamed block by block; with --subsurface one block, the operator coupling every seen texel),
    then truth/, the preview, settings.json and index.html into ``tmp`` (the result set swapped to ``out``)."""
    times, memory = {}, {}
    t0 = time.perf_counter()
    spec = mesh_from_args(args)
    mesh, full = texel_surface(spec, args.resolution, where=str(spec["path"]))
    rig, rig_desc = parse_rig(args.rig, args.rig_units, args.rig_up)
    warn_mesh_size("simulate", mesh, rig)
    cams = parse_cameras(args.camera, mesh, args.image_size)
    times["geometry_s"], memory["geometry"] = time.perf_counter() - t0, _memory()
    t0 = time.perf_counter()
    cam_vis = stage.camera_visibility(mesh, full, cams, chunk=_CAMERA_CHUNK)
    seen = np.nonzero(np.any(cam_vis, axis=0))[0]
    if len(seen) == 0:
        raise CLIError(f"--camera {args.camera}: no texel of the mesh is seen by any camera")
    surface, cam_vis = full.subset(seen), cam_vis[:, seen]
    times["camera_visibility_s"] = time.perf_counter() - t0
    rho, f0, alpha, truth, sss, mfp, model, sss_info = _truth(args, sss_source, surface, times)
    (H, W), V, L, C = full.resolution, len(cams), rig.num_lights, 3
    del full  # only the seen texels from here (the grid's surface is ~70 B a texel)
    memory["camera_visibility"] = _memory()
    dtype = np.float16 if args.half else np.float32
    metadata = {"space": "texel", "surface": {**spec, "resolution": [H, W]}, "rig": rig_desc,
                "material": ("relight demo skin (Lambert + GGX, F0 0.028, alpha 0.2-0.5), ground truth in truth/"
                             if sss_info is None else "relight demo skin (GGX, F0 0.028, alpha 0.2-0.5, + subsurface "
                             "scattering: Burley profile of albedo rho_d and the mean free path of "
                             "metadata.subsurface), ground truth in truth/"),
                "subsurface": sss_info, "noise": _noise_meta(args, sensor, "texel"),
                "units": {"lengths": "mm", "radiance": "relative to the rig's irradiance"},
                "writer": "relight simulate"}
    if store:
        block, pc = store_blocks(H * W, DEFAULT_BLOCK if args.block is None else args.block, C, dtype)
        writer = CaptureStoreWriter(tmp, (V, L, H * W, C), dtype, rig, cams, metadata, (1, 8, pc, C),
                                    sample_shape=(H, W))
        lc = _STORE_LIGHT_CHUNK if sss is None else _SSS_STORE_LIGHT_CHUNK
    else:
        block, lc = H * W, _FOLDER_LIGHT_CHUNK
        writer = CaptureFolderWriter(tmp, (V, L, H * W, C), dtype, rig, cams, metadata, sample_shape=(H, W))
    t0 = time.perf_counter()
    with writing(out), writer, bar(V * L, f"simulate ({'store' if store else 'capture'})", args.quiet) as b:
        done = stage.simulate_into(writer, mesh, surface, rig, cams, truth, cam_vis, subsurface=sss, sensor=sensor,
                                   seed=args.seed, block=block, light_chunk=lc, progress=b)
    times["visibility_s"], times["simulate_s"] = done.visibility_s, time.perf_counter() - t0 - done.visibility_s
    memory["simulate"] = _memory()
    t0 = time.perf_counter()
    _write_extras(tmp, mesh, cams, surface, (H, W), done.all_lights,
                  material_maps(surface, rho, f0, alpha, mfp=mfp, model=model), spec, sss_info)
    times["write_s"], memory["write"] = time.perf_counter() - t0, _memory()
    form = {"form": "store", "block_texels": done.block, "store_chunks": [1, 8, int(pc), C],
            "blocks": done.blocks} if store else {}
    write_settings(tmp, "simulate", args, mesh=metadata["surface"], rig=rig_desc, lights=L, views=V,
                   samples_seen=int(len(seen)), texels=[H, W], subsurface=sss_info, **form,
                   timings_s={k: round(v, 3) for k, v in times.items()}, peak_rss_mib=memory)
    if not args.no_index:
        def sweeps():  # the capture read back whole, unless it is too large for that (the page then says so)
            from ..view import folder_sweeps

            return folder_sweeps(tmp, None, INDEX_FRAMES, INDEX_SIZE)

        write_index_page(tmp, sweeps, "simulate", args.quiet, location=out)
    if summary(args):
        tail = "" if sss_info is None else (f", subsurface {sss_info['source']}: mfp "
                                            + "/".join(f"{x:.3g}" for x in sss_info["mfp_mm"]) + " mm (R/G/B)")
        what = f"capture store: {V} view(s)" if store else f"{V} view(s)"
        blocks = f", {done.blocks} blocks of {done.block} texels" if store else ""
        print(f"wrote {out}{'' if store else '/'} ({what} x {L} lights, {len(seen)} of {H}x{W} texels seen{tail}"
              f"{blocks})")
    return 0


def _truth(args, sss_source, surface, times):
    """The demo material on the seen samples: (rho, f0, alpha, truth brdf, Subsurface or None, mfp or None,
    model or None, the subsurface report or None)."""
    rho, f0, alpha = demo_material(surface)
    truth = brdf.lambert_ggx(rho, f0, alpha)
    if sss_source is None:
        return rho, f0, alpha, truth, None, None, None, None
    t0 = time.perf_counter()
    kind, source, eta = sss_source
    with bar(None, "subsurface (diffusion operator)", args.quiet) as b:
        b("neighbours", 0, None)
        mfp = mean_free_path_at(source, surface)
        if not np.any(mfp > 0):
            raise CLIError(f"--subsurface {args.subsurface}: the mean free path is 0 at every texel the camera "
                           "sees (no subsurface scattering); omit --subsurface")
        sss = stage.subsurface_from_maps(surface, rho, mfp, eta)
    on = np.any(mfp > 0, axis=1)
    # Subsurface texels take their diffuse light from the operator; the others keep the local Lambert term.
    truth = brdf.Sum(brdf.Lambert(np.asarray(rho) * (~on)[:, None]), stage.split_material(truth)[1])
    model = np.where(on, SUBSURFACE, GGX).astype(np.int32)
    sss_info = {"source": f"preset {args.subsurface}" if kind == "preset" else str(Path(args.subsurface)),
                "mfp_scale": args.mfp_scale, "eta": eta,
                "mfp_mm": (source.tolist() if kind == "preset"
                           else np.median(mfp[on], axis=0).tolist()),  # a map: the median over subsurface texels
                "subsurface_samples": int(on.sum()),
                "profile": "Burley dmfp (Christensen & Burley 2015), albedo = the diffuse albedo rho_d",
                "operator": {"radius_mm": round(float(sss.operator.radius), 4),
                             "energy_fraction": skin_bssrdf.OPERATOR_ENERGY,
                             "max_neighbours": int(sss.operator.index.shape[1])}}
    times["subsurface_operator_s"] = time.perf_counter() - t0
    return rho, f0, alpha, truth, sss, mfp, model, sss_info


def _write_extras(out: Path, mesh, cams, surface, resolution, all_on, truth_maps, spec, sss_info) -> None:
    """truth/ (the ground-truth map set, with its previews) and the preview (view 0, every light on:
    ``all_on`` [H*W, C] on the texel grid) into ``out``."""
    H, W = resolution
    truth_meta = {"source": "relight simulate ground truth"}
    if sss_info is not None:
        truth_meta["subsurface"] = {"eta": sss_info["eta"], "source": sss_info["source"]}
    covered = np.zeros((H, W), bool)
    covered.reshape(-1)[np.asarray(surface.texel_index)] = True
    write_maps(out / "truth", truth_maps, surface, surface_info=spec, metadata=truth_meta)
    # truth/'s previews, as `relight fit` writes its own, added to truth/'s manifest (truth/ is inside the capture
    # being built at `out`, under its lock: no reader sees it before the whole capture is swapped in).
    grid = lambda x: dilate(surface.to_texture(np.asarray(x, np.float32)), covered)  # noqa: E731
    write_map_previews(out / "truth", grid(truth_maps.rho_d), grid(truth_maps.rho_s),
                       grid(np.asarray(truth_maps.alpha)[:, :1]))
    open_result_set(out / "truth").add("albedo.png", "specular.png", "roughness.png")
    view = texture_view(mesh, cams[0], {"all_lights": dilate(all_on.reshape(H, W, -1), covered)})["all_lights"]
    with writing(out / "preview_all_lights.exr"):
        write_exr(out / "preview_all_lights.exr", view)
    write_preview(out / "preview_all_lights.png", view)


def _run_image(args, out: Path, sensor, tmp: Path) -> int:
    """``--space image``: ``stage.simulate_images`` written as a photo capture
    (``relight.io.write_photo_capture``) with each camera's mask (the pixels that see the mesh)."""
    t0 = time.perf_counter()
    spec = mesh_from_args(args)
    mesh = spec_mesh(spec, str(spec["path"]))
    rig, rig_desc = parse_rig(args.rig, args.rig_units, args.rig_up)
    warn_mesh_size("simulate", mesh, rig)
    cams = parse_cameras(args.camera, mesh, args.image_size)
    with bar(rig.num_lights * len(cams), "simulate (lights)", args.quiet) as b:
        try:
            images, masks = stage.simulate_images(mesh, rig, cams, lambda s: brdf.lambert_ggx(*demo_material(s)),
                                                  sensor=sensor, seed=args.seed, progress=b)
        except ValueError as err:
            if not str(err).startswith("camera "):
                raise
            raise CLIError(f"--camera {args.camera}: {err}") from None
    times = {"simulate_s": time.perf_counter() - t0}
    metadata = {"space": "image", "mesh": spec, "rig": rig_desc, "noise": _noise_meta(args, sensor, "pixel"),
                "material": "relight demo skin (Lambert + GGX, F0 0.028, alpha 0.2-0.5)",
                "units": {"lengths": "mm", "radiance": "relative to the rig's irradiance"},
                "writer": "relight simulate --space image"}
    t0 = time.perf_counter()
    with writing(out):
        write_photo_capture(tmp, images, rig, cams, half=args.half, masks=masks, metadata=metadata)
    all_on = images[0].sum(axis=0)
    with writing(tmp / "preview_all_lights.exr"):
        write_exr(tmp / "preview_all_lights.exr", all_on)
    write_preview(tmp / "preview_all_lights.png", all_on)
    times["write_s"] = time.perf_counter() - t0
    write_settings(tmp, "simulate", args, mesh=spec, rig=rig_desc, lights=rig.num_lights, views=len(cams),
                   pixels_seen=[int(m.sum()) for m in masks], timings_s={k: round(v, 3) for k, v in times.items()})
    if not args.no_index:
        def sweeps():
            from ..envmap import bundled_envmap_path, load_envmap
            from ..view import photo_sweep

            return [photo_sweep(images[0], masks[0], rig, load_envmap(bundled_envmap_path()), INDEX_FRAMES,
                                "camera 0's photographs relit image-based (bundled map)")], None

        write_index_page(tmp, sweeps, "simulate", args.quiet, location=out)
    if summary(args):
        print(f"wrote {out}/ ({len(cams)} camera(s) x {rig.num_lights} lights, photo capture)")
    return 0

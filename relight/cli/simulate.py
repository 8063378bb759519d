"""``relight simulate``: render an OLAT capture of a mesh with the demo's
skin-like ground-truth material, and write it as a texel-space capture folder
(``--space texel``) or as a camera-space photo capture (``--space image``: one
image per camera and light, docs/capture_layout.md).

``--subsurface PRESET|MAP`` (texel space only) replaces the material's local
Lambert term by subsurface scattering: Jensen et al. 2001's eq. 5 through
``skin_bssrdf.DiffusionOperator`` (``stage.Subsurface``) with Christensen &
Burley 2015's profile, albedo = the demo's rho_d (the total diffuse
reflectance, unchanged) and the diffuse mean free path of a measured preset
or of an EXR map (mm).

``--out NAME.zarr`` (the rule ``relight convert`` uses: a name ending in
``.zarr`` is a capture store, any other a capture folder) streams the capture
into a Zarr v3 capture store (``relight.io.CaptureStoreWriter``) instead of
holding it: the texel grid is cut into blocks of ``--block`` texels, and per
block only its seen texels get light visibility (``stage.light_visibility``),
``stage.simulate_chunks`` and sensor noise, each chunk written as it comes, so
peak memory is set by the block, not by the texel count. The store holds the
full texel grid [V, L, H*W, C] (unseen and off-chart texels 0 and invalid), as
the folder form and ``relight convert`` of it do, so both read the same.
``truth/``, the preview and settings.json go inside the store folder, which is
built under a temporary name and renamed into place whole.

Sensor noise (``--noise``) is seeded per observation: the key of (view v,
light l, texel t) is fold_in(fold_in(fold_in(PRNGKey(seed), v), l), t), so a
capture's noise does not depend on the block or chunk sizes, nor on the form it
is written in."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

# JAX, equinox, brdf, skin_bssrdf, stage and the rest of relight are imported inside the functions that use
# them (the module's __getattr__ gives the names below on first use), so that `relight simulate --help` builds
# its parser without them, as the other commands do (tests/relight/test_cli_ux.py).
from ._common import (
    INDEX_FRAMES,
    INDEX_SIZE,
    MIN_IMAGE_SIZE,
    SUBSURFACE_ENERGY,
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
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    import brdf
    import skin_bssrdf
    import stage

    from ..image._preview import dilate, sample_texture, texture_view
    from ..io import (
        CaptureStoreWriter,
        default_chunks,
        read_exr,
        spec_mesh,
        texel_surface,
        write_capture,
        write_exr,
        write_maps,
        write_photo_capture,
    )
    from ..io._resultset import open_result_set, write_manifest
    from ..io._store import MARKER as _STORE_MARKER
    from ..materials._maps import GGX, SUBSURFACE, material_maps

# The library names this module uses, imported on first use: name -> (module, attribute). :func:`_load` puts
# them all into the module's globals (``run`` and the functions used from outside call it first); reading one
# as an attribute (``relight.cli.simulate.texel_surface``) loads it too (PEP 562). A name a test or script has
# replaced (``relight.cli.simulate.texel_surface = ...``) is kept.
_LAZY = {
    "eqx": ("equinox", None), "jax": ("jax", None), "jnp": ("jax.numpy", None), "brdf": ("brdf", None),
    "skin_bssrdf": ("skin_bssrdf", None), "stage": ("stage", None),
    "dilate": ("relight.image._preview", "dilate"), "sample_texture": ("relight.image._preview", "sample_texture"),
    "texture_view": ("relight.image._preview", "texture_view"),
    **{n: ("relight.io", n) for n in ("CaptureStoreWriter", "default_chunks", "read_exr", "spec_mesh",
                                      "texel_surface", "write_capture", "write_exr", "write_maps",
                                      "write_photo_capture")},
    "open_result_set": ("relight.io._resultset", "open_result_set"),
    "write_manifest": ("relight.io._resultset", "write_manifest"),
    "_STORE_MARKER": ("relight.io._store", "MARKER"),  # the manifest: only a finished store is replaced
    "GGX": ("relight.materials._maps", "GGX"), "SUBSURFACE": ("relight.materials._maps", "SUBSURFACE"),
    "material_maps": ("relight.materials._maps", "material_maps"),
}


# relight.cli._common.SUBSURFACE_PRESETS (the --subsurface presets, read from skin_bssrdf), spelled here for the
# help text so that building the parser needs no JAX; tests/relight/test_cli_ux.py checks it against _common's.
_PRESET_NAMES = ("apple", "chicken1", "chicken2", "cream", "ketchup", "marble", "potato", "skimmilk", "skin1", "skin2",
                 "wholemilk")


def _import(name: str):
    import importlib

    module, attr = _LAZY[name]
    value = importlib.import_module(module)
    return value if attr is None else getattr(value, attr)


def _load() -> None:
    """Import the library names of ``_LAZY`` into this module's globals (those not already set)."""
    g = globals()
    for name in _LAZY:
        if name not in g:
            g[name] = _import(name)


def __getattr__(name: str):
    if name in _LAZY:
        value = globals()[name] = _import(name)
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


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
# Texels of the grid per block of the store form: one store chunk's width, so a
# block writes whole chunks. Its working set (the block's visibility [n, L] bools,
# the shading temporaries of a 16-light chunk, the scattered chunk) stayed under
# ~60 MiB at 346 lights; blocks of 65536 texels cost ~60 MiB more at the same
# speed (docs/figures/pipeline_memory.md).
DEFAULT_BLOCK = 1 << 14
# Lights per simulate_chunks chunk in the store form: two store chunks' worth
# (relight.io's LIGHT_CHUNK = 8), so every write completes its store chunks.
_STORE_LIGHT_CHUNK = 16
# Lights per chunk when the capture is in memory (the folder form), stage.simulate's default.
_FOLDER_LIGHT_CHUNK = 64


# The mean free path floor of a subsurface texel's zero channels: MaterialMaps.profile's, so that the
# simulation and relight.render's profile of the truth maps agree.
_MFP_FLOOR_MM = 1e-3


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
    if path.is_file() or path.suffix.lower() == ".exr":
        if not path.is_file():
            raise CLIError(f"--subsurface {path}: no such mean-free-path EXR")
        try:
            mfp = np.asarray(read_exr(path), np.float64)
        except ValueError as err:
            raise CLIError(f"--subsurface {path}: {err}") from None
        if mfp.shape[-1] == 1:
            mfp = np.repeat(mfp, 3, axis=-1)
        elif mfp.shape[-1] != 3:
            raise CLIError(f"--subsurface {path}: a mean free path map has 3 channels (R, G, B) or 1 (Y), "
                           f"this one {mfp.shape[-1]}")
        if not np.all(np.isfinite(mfp)):
            raise CLIError(f"--subsurface {path}: the mean free path map has NaN or Inf values")
        if np.any(mfp < 0):
            raise CLIError(f"--subsurface {path}: the mean free path map has negative values (min "
                           f"{mfp.min():.3g}; mm, >= 0)")
        return "map", mfp * args.mfp_scale, 1.4 if args.eta is None else args.eta
    mfp, eta = preset_mean_free_path(args.subsurface)
    return "preset", mfp * args.mfp_scale, eta if args.eta is None else args.eta


def _mfp_at(kind: str, mfp, full: stage.Surface, surface: stage.Surface, where: str) -> np.ndarray:
    """The mean free path [P, 3] (mm) at the surface's samples: the preset's
    everywhere, or the map's texel (bilinear at the samples' uv if the map is
    not on the texel grid's size)."""
    if kind == "preset":
        return np.broadcast_to(mfp, (surface.num_samples, 3)).copy()
    if tuple(mfp.shape[:2]) == tuple(full.resolution):
        out = mfp.reshape(-1, 3)[np.asarray(surface.texel_index)]
    else:
        out = sample_texture(mfp, np.asarray(surface.uv, np.float64))
    if not np.any(out > 0):
        raise CLIError(f"--subsurface {where}: the mean free path is 0 at every texel the camera sees "
                       "(no subsurface scattering); omit --subsurface")
    return out


def _subsurface(surface: stage.Surface, rho, mfp: np.ndarray, eta: float):
    """stage.Subsurface on the seen samples and the model of each: texels with
    mfp > 0 in some channel scatter (albedo rho, profile Burley ``dmfp``),
    the others keep the local Lambert term (returned as its albedo, 0 on
    subsurface texels). Returns (Subsurface, local albedo [P, 3], model [P],
    operator radius in mm)."""
    on = np.any(mfp > 0, axis=1)
    rho64 = np.asarray(rho, np.float64)
    op_dt = jnp.float64 if jax.config.jax_enable_x64 else jnp.float32
    prof = skin_bssrdf.Burley.from_mean_free_path(jnp.asarray(rho64 * on[:, None], op_dt),
                                                  jnp.asarray(np.maximum(mfp, _MFP_FLOOR_MM), op_dt), config="dmfp")
    radius = float(np.max(np.asarray(skin_bssrdf.energy_radius(prof, SUBSURFACE_ENERGY))[on]))
    op = skin_bssrdf.DiffusionOperator.build(np.asarray(surface.position), np.asarray(surface.area), radius,
                                             dtype=op_dt)
    local = jnp.asarray(rho64 * (~on)[:, None], jnp.asarray(rho).dtype)
    model = np.where(on, SUBSURFACE, GGX).astype(np.int32)
    return stage.Subsurface(prof, op, float(eta)), local, model, radius


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


def _sense_chunk(*args):
    """``_sense_chunk_body`` compiled (``equinox.filter_jit``, made on first use so that importing this module
    needs no JAX)."""
    global _SENSE_JIT
    if _SENSE_JIT is None:
        _SENSE_JIT = eqx.filter_jit(_sense_chunk_body)
    return _SENSE_JIT(*args)


_SENSE_JIT = None


def _sense_chunk_body(sensor: stage.Sensor, key, view, light0, texels, radiance, mask):
    """``stage.Sensor.expose`` on one chunk (radiance [Lc, Pc, C], mask [Lc, Pc]),
    each observation seeded by its own key fold_in(fold_in(fold_in(key, view),
    light), texel) (light = light0 + row, texel = ``texels`` [Pc], its index on
    the texel grid), so the noise of an observation is the same whatever chunk
    it is drawn in. Returns (radiance in capture units [Lc, Pc, C], mask without
    the saturated observations)."""
    kv = jax.random.fold_in(key, view)
    lights = jnp.asarray(light0, jnp.int32) + jnp.arange(radiance.shape[0], dtype=jnp.int32)

    def one(light, texel, rad):
        return sensor.expose(jax.random.fold_in(jax.random.fold_in(kv, light), texel), rad)

    dn, sat = jax.vmap(lambda lt, r: jax.vmap(lambda t, x: one(lt, t, x))(texels, r))(lights, radiance)
    return sensor.to_radiance(dn).astype(radiance.dtype), mask & ~sat


def sense_chunk(sensor: stage.Sensor | None, seed: int, view: int, light0: int, texels, radiance, mask):
    """Sensor noise of one chunk of a texel capture, reproducible per
    observation (see ``_sense_chunk``): NumPy (radiance [Lc, Pc, C] float32 >= 0,
    mask [Lc, Pc] bool). ``sensor`` None: the chunk as it is (clipped at 0)."""
    _load()
    if sensor is not None:
        radiance, mask = _sense_chunk(sensor, jax.random.PRNGKey(seed), jnp.asarray(view, jnp.int32),
                                      jnp.asarray(light0, jnp.int32), jnp.asarray(texels, jnp.int32),
                                      jnp.asarray(radiance, jnp.float32), jnp.asarray(mask, bool))
    return np.maximum(np.asarray(radiance, np.float32), 0.0), np.asarray(mask, bool)


def _peak_rss_mib() -> float | None:
    """The process's peak resident set so far (MiB; Linux ru_maxrss is KiB), None where unknown."""
    try:
        import resource

        return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1)
    except (ImportError, OSError):  # pragma: no cover - not on Linux / macOS
        return None


def _check_form(args, out: Path) -> bool:
    """True for the store form (``--out`` ending in .zarr); CLIError naming the
    flag for a combination that contradicts the form."""
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
    """What an earlier simulate wrote before result-set manifests (a capture store, a capture folder, a photo
    capture), which this one may replace; anything else non-empty is refused (naming what it holds)."""
    if store:
        return lambda p: (p / _STORE_MARKER).is_file()
    if args.space == "image":
        from ..io import is_photo_capture

        return is_photo_capture
    return lambda p: (p / "capture.json").is_file()


def _truth(args, sss_source, full, surface, quiet, times):
    """The demo material on the seen samples: (rho, f0, alpha, truth brdf,
    Subsurface or None, mfp or None, model or None, the subsurface report or None)."""
    rho, f0, alpha = demo_material(surface)
    truth = brdf.lambert_ggx(rho, f0, alpha)
    if sss_source is None:
        return rho, f0, alpha, truth, None, None, None, None
    t0 = time.perf_counter()
    kind, source, eta = sss_source
    with bar(None, "subsurface (diffusion operator)", quiet) as b:
        b("neighbours", 0, None)
        mfp = _mfp_at(kind, source, full, surface, args.subsurface)
        sss, local, model, radius = _subsurface(surface, rho, mfp, eta)
    _, specular = stage.split_material(truth)
    truth = brdf.Sum(brdf.Lambert(local), specular)
    on = model == SUBSURFACE
    sss_info = {"source": f"preset {args.subsurface}" if kind == "preset" else str(Path(args.subsurface)),
                "mfp_scale": args.mfp_scale, "eta": eta,
                "mfp_mm": (source.tolist() if kind == "preset"
                           else np.median(mfp[on], axis=0).tolist()),  # a map: the median over subsurface texels
                "subsurface_samples": int(on.sum()),
                "profile": "Burley dmfp (Christensen & Burley 2015), albedo = the diffuse albedo rho_d",
                "operator": {"radius_mm": round(radius, 4), "energy_fraction": SUBSURFACE_ENERGY,
                             "max_neighbours": int(sss.operator.index.shape[1])}}
    times["subsurface_operator_s"] = time.perf_counter() - t0
    return rho, f0, alpha, truth, sss, mfp, model, sss_info


def _metadata(args, spec, resolution, rig_desc, sensor, sss_info) -> dict:
    """capture.json's (or the store manifest's) metadata: what load_texel_capture needs to rebuild the surface."""
    H, W = resolution
    noise = None if sensor is None else {"model": "poisson-gaussian", "exposure": float(args.noise),
                                         "read_noise": args.read_noise, "seed": args.seed,
                                         "keys": "fold_in(fold_in(fold_in(PRNGKey(seed), view), light), texel)"}
    material = ("relight demo skin (Lambert + GGX, F0 0.028, alpha 0.2-0.5), ground truth in truth/"
                if sss_info is None else
                "relight demo skin (GGX, F0 0.028, alpha 0.2-0.5, + subsurface scattering: Burley profile of albedo "
                "rho_d and the mean free path of metadata.subsurface), ground truth in truth/")
    return {"space": "texel", "surface": {**spec, "resolution": [H, W]}, "rig": rig_desc, "material": material,
            "subsurface": sss_info, "noise": noise,
            "units": {"lengths": "mm", "radiance": "relative to the rig's irradiance"},
            "writer": "relight simulate"}


def _write_extras(out: Path, mesh, cams, surface, resolution, all_on, truth_maps, spec, sss_info) -> None:
    """truth/ (the ground-truth map set) and the preview (view 0, every light on:
    ``all_on`` [H*W, C] on the texel grid) into ``out``."""
    H, W = resolution
    truth_meta = {"source": "relight simulate ground truth"}
    if sss_info is not None:
        truth_meta["subsurface"] = {"eta": sss_info["eta"], "source": sss_info["source"]}
    covered = np.zeros((H, W), bool)
    covered.reshape(-1)[np.asarray(surface.texel_index)] = True
    write_maps(out / "truth", truth_maps, surface, surface_info=spec, metadata=truth_meta)
    # truth/'s previews, as `relight fit` writes its own, then truth/'s manifest again so that it lists them
    # (truth/ is inside the capture being built at `out`: no reader sees it before the whole capture is swapped in).
    grid = lambda x: dilate(surface.to_texture(np.asarray(x, np.float32)), covered)  # noqa: E731
    write_map_previews(out / "truth", grid(truth_maps.rho_d), grid(truth_maps.rho_s),
                       grid(np.asarray(truth_maps.alpha)[:, :1]))
    truth_set = open_result_set(out / "truth")
    write_manifest(out / "truth", truth_set.kind, truth_set.manifest.get("unhashed") or ())
    view = texture_view(mesh, cams[0], {"all_lights": dilate(all_on.reshape(H, W, -1), covered)})["all_lights"]
    with writing(out / "preview_all_lights.exr"):
        write_exr(out / "preview_all_lights.exr", view)
    write_preview(out / "preview_all_lights.png", view)


def _geometry(args, times):
    """(mesh spec, mesh, full texel surface, rig, rig description, cameras) of the flags."""
    t0 = time.perf_counter()
    spec = mesh_from_args(args)
    mesh, full = texel_surface(spec, args.resolution, where=str(spec["path"]))
    rig, rig_desc = parse_rig(args.rig, args.rig_units, args.rig_up)
    warn_mesh_size("simulate", mesh, rig)
    cams = parse_cameras(args.camera, mesh, args.image_size)
    times["geometry_s"] = time.perf_counter() - t0
    return spec, mesh, full, rig, rig_desc, cams


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
        if store:
            return _run_store(args, out, sensor, sss_source, tmp)
        return _run_folder(args, out, sensor, sss_source, tmp)


def _run_folder(args, out: Path, sensor, sss_source, tmp: Path) -> int:
    """The capture-folder form, simulated in memory and written to ``tmp`` (the result set swapped to ``out``)."""
    times = {}
    spec, mesh, full, rig, rig_desc, cams = _geometry(args, times)
    t0 = time.perf_counter()
    with bar(full.num_samples * rig.num_lights, "visibility (rays)", args.quiet) as b:
        light_vis = stage.light_visibility(mesh, full, rig, chunk=1 << 18, progress=b)
    cam_vis = stage.camera_visibility(mesh, full, cams)
    seen = np.nonzero(np.any(cam_vis, axis=0))[0]
    if len(seen) == 0:
        raise CLIError(f"--camera {args.camera}: no texel of the mesh is seen by any camera")
    surface = full.subset(seen)
    light_vis, cam_vis = light_vis[seen], cam_vis[:, seen]
    times["visibility_s"] = time.perf_counter() - t0

    rho, f0, alpha, truth, sss, mfp, model, sss_info = _truth(args, sss_source, full, surface, args.quiet, times)
    t0 = time.perf_counter()
    with bar(rig.num_lights * len(cams), "simulate (lights)", args.quiet) as b:
        capture = stage.simulate(surface, rig, cams, truth, light_vis, cam_vis, subsurface=sss, progress=b,
                                 light_chunk=_FOLDER_LIGHT_CHUNK)
    # Store on the full texel grid: every light image is a texture (viewable in
    # any EXR viewer); texels without a seen sample are 0 and marked invalid.
    H, W = full.resolution
    V, L, _, C = capture.radiance.shape
    idx = np.asarray(surface.texel_index)
    radiance = np.zeros((V, L, H * W, C), np.float32)
    valid = np.zeros((V, L, H * W), bool)
    for v in range(V):
        for l0 in range(0, L, _FOLDER_LIGHT_CHUNK):
            ls = slice(l0, min(l0 + _FOLDER_LIGHT_CHUNK, L))
            r, m = sense_chunk(sensor, args.seed, v, l0, idx, capture.radiance[v, ls], capture.mask[v, ls])
            radiance[v, ls][:, idx] = r  # (radiance[v, ls, idx] would put the texel axis first)
            valid[v, ls][:, idx] = m
    del capture
    times["simulate_s"] = time.perf_counter() - t0
    metadata = _metadata(args, spec, full.resolution, rig_desc, sensor, sss_info)
    t0 = time.perf_counter()
    with writing(out):
        write_capture(tmp, radiance, rig, cams, valid=valid, metadata=metadata, sample_shape=(H, W), half=args.half)
    _write_extras(tmp, mesh, cams, surface, full.resolution, radiance[0].sum(axis=0),
                  material_maps(surface, rho, f0, alpha, mfp=mfp, model=model), spec, sss_info)
    times["write_s"] = time.perf_counter() - t0
    write_settings(tmp, "simulate", args, mesh=metadata["surface"], rig=rig_desc, lights=rig.num_lights,
                   views=len(cams), samples_seen=int(len(seen)), texels=[H, W], subsurface=sss_info,
                   timings_s={k: round(v, 3) for k, v in times.items()})
    if not args.no_index:
        write_index_page(tmp, lambda: _capture_index(radiance, valid, idx, rig, cams, surface, mesh), "simulate",
                         args.quiet, location=out)
    if summary(args):
        tail = "" if sss_info is None else (f", subsurface {sss_info['source']}: mfp "
                                            + "/".join(f"{x:.3g}" for x in sss_info["mfp_mm"]) + " mm (R/G/B)")
        print(f"wrote {out}/ ({V} view(s) x {L} lights, {len(seen)} of {H}x{W} texels seen{tail})")
    return 0


def _capture_index(radiance, valid, idx, rig, cams, surface, mesh):
    """index.html's slider: the capture as it was written (noise, invalid observations; ``radiance`` [V, L,
    H*W, C] on the grid, ``idx`` the seen texels) relit image-based under the bundled map (``relight.view``),
    unless it is larger than a page's sweep takes (the page then says so)."""
    from ..envmap import bundled_envmap_path, load_envmap
    from ..view import capture_sweep
    from ..view._sweep import MAX_CAPTURE_VALUES

    V, L, _, C = radiance.shape
    if V * L * len(idx) * C > MAX_CAPTURE_VALUES:
        return [], (f"no rotation slider: the capture holds {V * L * len(idx) * C:,} values, more than the "
                    f"{MAX_CAPTURE_VALUES:,} a page's sweep relights (relight render OUT --frames N makes a turntable)")
    held = stage.Capture(radiance=jnp.asarray(radiance[:, :, idx]), mask=jnp.asarray(valid[:, :, idx]), rig=rig,
                         cameras=tuple(cams))
    return [capture_sweep(held, surface, mesh, cams[0], load_envmap(bundled_envmap_path()), INDEX_FRAMES,
                          INDEX_SIZE, "the capture relit image-based (bundled map)")], None


def store_blocks(n_texels: int, block: int, channels: int, dtype) -> tuple[int, int]:
    """(texels per block, store sample chunk) of the store form for a grid of
    ``n_texels`` and ``--block``: the chunk is relight.io's default (about 2 MiB
    of 8 lights) or the largest power of two <= block if smaller, and the block
    is rounded down to a multiple of it, so every block writes whole chunks."""
    _load()
    pc = default_chunks((1, 8, n_texels, channels), dtype)[2]
    pc = max(1, min(pc, 1 << int(math.floor(math.log2(max(1, block))))))
    return max(pc, (block // pc) * pc), pc


def _run_store(args, out: Path, sensor, sss_source, tmp: Path) -> int:
    """The store form: stream the capture into a capture store block by block
    (module docstring). With --subsurface the operator couples every seen texel,
    so there is one block (the whole grid) and the light chunk is a store chunk's 8."""
    times, memory = {}, {}
    spec, mesh, full, rig, rig_desc, cams = _geometry(args, times)
    memory["geometry"] = _peak_rss_mib()
    _return_freed_memory()
    t0 = time.perf_counter()
    cam_vis = _camera_visibility(mesh, full, cams)
    seen = np.nonzero(np.any(cam_vis, axis=0))[0]
    if len(seen) == 0:
        raise CLIError(f"--camera {args.camera}: no texel of the mesh is seen by any camera")
    surface = full.subset(seen)
    cam_vis = cam_vis[:, seen]
    times["camera_visibility_s"] = time.perf_counter() - t0
    rho, f0, alpha, truth, sss, mfp, model, sss_info = _truth(args, sss_source, full, surface, args.quiet, times)
    memory["camera_visibility"] = _peak_rss_mib()
    H, W = full.resolution
    del full  # only the seen texels from here (the grid's surface is ~70 B a texel)
    _return_freed_memory()

    V, L, C = len(cams), rig.num_lights, 3
    dtype = np.float16 if args.half else np.float32
    block, pc = store_blocks(H * W, DEFAULT_BLOCK if args.block is None else args.block, C, dtype)
    if sss is not None:
        block = H * W
    metadata = _metadata(args, spec, (H, W), rig_desc, sensor, sss_info)
    t0 = time.perf_counter()
    # The store is built at tmp; output_set swaps the whole folder (store, truth/, settings) in.
    with CaptureStoreWriter(tmp, (V, L, H * W, C), dtype, rig, cams, metadata, (1, 8, pc, C),
                            sample_shape=(H, W)) as writer:
        all_on, n_blocks, t_vis = _stream(writer, args, mesh, rig, cams, surface, cam_vis, (rho, f0, alpha),
                                          truth, sss, sensor, block)
    times["visibility_s"] = t_vis
    times["simulate_s"] = time.perf_counter() - t0 - t_vis
    memory["simulate"] = _peak_rss_mib()
    _return_freed_memory()
    t0 = time.perf_counter()
    _write_extras(tmp, mesh, cams, surface, (H, W), all_on,
                  material_maps(surface, rho, f0, alpha, mfp=mfp, model=model), spec, sss_info)
    times["write_s"] = time.perf_counter() - t0
    memory["write"] = _peak_rss_mib()
    write_settings(tmp, "simulate", args, mesh=metadata["surface"], rig=rig_desc, lights=L, views=V,
                   samples_seen=int(len(seen)), texels=[H, W], subsurface=sss_info, form="store",
                   block_texels=int(block), store_chunks=[1, 8, int(pc), C], blocks=n_blocks,
                   timings_s={k: round(v, 3) for k, v in times.items()}, peak_rss_mib=memory)
    if not args.no_index:
        def sweeps():  # the store read back whole, unless it is too large for that (the page then says so)
            from ..view import folder_sweeps

            return folder_sweeps(tmp, None, INDEX_FRAMES, INDEX_SIZE)

        write_index_page(tmp, sweeps, "simulate", args.quiet, location=out)
    if summary(args):
        print(f"wrote {out} (capture store: {V} view(s) x {L} lights, {len(seen)} of {H}x{W} texels seen, "
              f"{n_blocks} blocks of {block} texels)")
    return 0


def _stream(writer, args, mesh, rig, cams, surface, cam_vis, params, truth, sss, sensor, block: int):
    """Simulate block by block into ``writer``: per block of ``block`` grid
    texels, the light visibility of its seen texels, ``stage.simulate_chunks``,
    sensor noise, each chunk scattered onto the block's texels and written.
    Returns (view 0 with every light on [H*W, C], blocks, seconds of visibility)."""
    H, W = surface.resolution
    V, L, C = len(cams), rig.num_lights, 3
    lc = _STORE_LIGHT_CHUNK if sss is None else 8
    # Blocks are cut on the host (_host_subset): an eager JAX op compiles once per shape, and every
    # block has its own seen count, so each block would add ~15 MiB of executables that are never freed.
    host = _host_fields(surface)
    params = [np.asarray(x) for x in params]
    tex = host["texel_index"]
    edges = np.unique(np.arange(0, H * W + block, block).clip(max=H * W))
    starts = np.searchsorted(tex, edges)  # the seen samples of block k: starts[k]:starts[k + 1]
    counts = np.diff(starts)
    # Every block's seen samples padded to one length (repeating its last): the kernels compile once.
    pad_to = surface.num_samples if sss is not None else int(-(-int(counts.max()) // 128) * 128)
    all_on = np.zeros((H * W, C), np.float32)
    t_vis = 0.0
    with bar(V * L * len(counts), f"simulate into store ({len(counts)} blocks of {block} texels)", args.quiet) as b:
        for k, n in enumerate(counts):
            g0, g1 = int(edges[k]), int(edges[k + 1])
            if n == 0:  # nothing seen here: zeros, invalid
                for v in range(V):
                    for l0 in range(0, L, lc):
                        nl = min(lc, L - l0)
                        writer.write(v, slice(l0, l0 + nl), slice(g0, g1), np.zeros((nl, g1 - g0, C), np.float32),
                                     np.zeros((nl, g1 - g0), bool))
                        b.update(nl)
                continue
            rows = np.arange(starts[k], starts[k + 1])
            pad = np.minimum(np.arange(starts[k], starts[k] + pad_to), starts[k + 1] - 1)
            t1 = time.perf_counter()
            b(f"block {k + 1}/{len(counts)}: light visibility", 0, None)
            lv = stage.light_visibility(mesh, _host_subset(host, (H, W), rows), rig, chunk=1 << 18)
            t_vis += time.perf_counter() - t1
            lv = lv[np.minimum(np.arange(pad_to), n - 1)]
            if sss is not None:
                sub, material = surface, truth
            else:
                sub = _host_subset(host, (H, W), pad)
                material = brdf.lambert_ggx(*(jax.device_put(x[pad]) for x in params))
            local = tex[rows] - g0
            b(f"block {k + 1}/{len(counts)}: simulate", 0, None)
            for v, ls, _, rad, msk in stage.simulate_chunks(sub, rig, cams, material, lv, cam_vis[:, pad],
                                                            light_chunk=lc, sample_chunk=pad_to, subsurface=sss):
                r, m = sense_chunk(sensor, args.seed, v, ls.start, tex[pad], rad, msk)
                nl = ls.stop - ls.start
                dense, dmask = np.zeros((nl, g1 - g0, C), np.float32), np.zeros((nl, g1 - g0), bool)
                dense[:, local], dmask[:, local] = r[:, :n], m[:, :n]
                writer.write(v, ls, slice(g0, g1), dense, dmask)
                if v == 0:
                    all_on[g0:g1] += dense.sum(axis=0)
                b.update(nl)
    return all_on, int(len(counts)), t_vis


# Texels per call of the store form's camera visibility pass.
_CAMERA_CHUNK = 1 << 16


def _camera_visibility(mesh, full: stage.Surface, cams) -> np.ndarray:
    """``stage.camera_visibility`` of the whole grid (bool [V, P]), ``_CAMERA_CHUNK``
    texels at a time: each texel's answer is its own ray, so the result is the
    same, while the pass's temporaries (the occluder's float64 copies, the
    projections and rays: ~270 B a texel, 260 MiB at 1024^2) stay one chunk's."""
    host = _host_fields(full)
    out = np.zeros((len(cams), full.num_samples), bool)
    for s in range(0, full.num_samples, _CAMERA_CHUNK):
        part = slice(s, min(s + _CAMERA_CHUNK, full.num_samples))
        out[:, part] = stage.camera_visibility(mesh, _host_subset(host, full.resolution, part), cams)
    return out


def _host_fields(surface: stage.Surface) -> dict:
    """The surface's fields as NumPy arrays (views of the JAX buffers on CPU: no copy)."""
    return {k: None if getattr(surface, k) is None else np.asarray(getattr(surface, k)) for k in _SURFACE_FIELDS}


def _return_freed_memory() -> None:
    """Hand freed heap back to the system (glibc's ``malloc_trim``; a no-op
    elsewhere): stage.texel_samples and the camera visibility of the whole grid
    free hundreds of bytes a texel of temporaries that glibc keeps (~250 MiB at
    1024^2), which would otherwise stay resident under the streaming and the
    writing that follow."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # pragma: no cover - not glibc
        pass


_SURFACE_FIELDS = ("position", "normal", "tangent", "bitangent", "uv", "area", "texel_index", "face", "barycentric")


def _host_subset(host: dict, resolution, index) -> stage.Surface:
    """``Surface.subset`` of a surface held as NumPy fields (``host``), with no JAX computation: jnp
    indexing and even ``jnp.asarray`` compile a program per new shape, ``jax.device_put`` does not."""
    return stage.Surface(**{k: None if v is None else jax.device_put(v[index]) for k, v in host.items()},
                         resolution=resolution)


def _run_image(args, out: Path, sensor, tmp: Path) -> int:
    """``--space image``: per camera, one sample per pixel (``stage.image_samples``),
    visibility, ``stage.simulate`` and the images [L, H, W, C] (0 off the
    mesh), written as a photo capture (``relight.io.write_photo_capture``) with
    each camera's mask (the pixels that see the mesh)."""

    times = {}
    t0 = time.perf_counter()
    spec = mesh_from_args(args)
    mesh = spec_mesh(spec, str(spec["path"]))
    rig, rig_desc = parse_rig(args.rig, args.rig_units, args.rig_up)
    warn_mesh_size("simulate", mesh, rig)
    cams = parse_cameras(args.camera, mesh, args.image_size)
    images, masks = [], []
    key = jax.random.PRNGKey(args.seed)
    with bar(rig.num_lights * len(cams), "simulate (lights)", args.quiet) as b:
        for v, cam in enumerate(cams):
            try:
                surface = stage.image_samples(mesh, cam)
            except ValueError as err:
                raise CLIError(f"--camera {args.camera}: camera {v}: {err}") from None
            light_vis = stage.light_visibility(mesh, surface, rig, chunk=1 << 18)
            cam_vis = stage.camera_visibility(mesh, surface, [cam])
            rho, f0, alpha = demo_material(surface)
            capture = stage.simulate(surface, rig, [cam], brdf.lambert_ggx(rho, f0, alpha), light_vis, cam_vis,
                                     progress=b)
            if sensor is not None:
                capture = stage.sense(capture, sensor, jax.random.fold_in(key, v))
            H, W = cam.height, cam.width
            idx = np.asarray(surface.texel_index)
            img = np.zeros((rig.num_lights, H * W, capture.radiance.shape[-1]), np.float32)
            img[:, idx] = np.maximum(np.asarray(capture.radiance[0], np.float32), 0.0)
            seen = np.zeros(H * W, bool)
            seen[idx] = np.asarray(cam_vis[0], bool)
            img[:, ~seen] = 0.0
            images.append(img.reshape(rig.num_lights, H, W, -1))
            masks.append(seen.reshape(H, W))
    times["simulate_s"] = time.perf_counter() - t0
    noise = None if sensor is None else {"model": "poisson-gaussian", "exposure": float(args.noise),
                                         "read_noise": args.read_noise, "seed": args.seed}
    metadata = {"space": "image", "mesh": spec, "rig": rig_desc, "noise": noise,
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

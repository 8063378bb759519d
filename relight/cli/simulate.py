"""``relight simulate``: render an OLAT capture of a mesh with the demo's
skin-like ground-truth material, and write it as a texel-space capture folder
(``--space texel``) or as a camera-space photo capture (``--space image``: one
image per camera and light, docs/capture_layout.md).

``--subsurface PRESET|MAP`` (texel space only) replaces the material's local
Lambert term by subsurface scattering: Jensen et al. 2001's eq. 5 through
``skin_bssrdf.DiffusionOperator`` (``stage.Subsurface``) with Christensen &
Burley 2015's profile, albedo = the demo's rho_d (the total diffuse
reflectance, unchanged) and the diffuse mean free path of a measured preset
or of an EXR map (mm)."""

from __future__ import annotations

import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import brdf
import skin_bssrdf
import stage

from ..image._preview import dilate, sample_texture, texture_view
from ..io import read_exr, spec_mesh, texel_surface, write_capture, write_exr, write_maps, write_photo_capture
from ..materials._maps import GGX, SUBSURFACE, material_maps
from ._common import (
    MIN_IMAGE_SIZE,
    SUBSURFACE_ENERGY,
    SUBSURFACE_PRESETS,
    CLIError,
    add_image_size,
    add_mesh_flags,
    add_out,
    add_rig_file_flags,
    at_least,
    bar,
    demo_material,
    finish_parser,
    mesh_from_args,
    parse_cameras,
    parse_rig,
    preset_mean_free_path,
    warn_mesh_size,
    write_preview,
    write_settings,
)


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
                        f"material of Jensen et al. 2001 ({', '.join(SUBSURFACE_PRESETS)}) giving the diffuse mean "
                        "free path per channel (and eta), or an EXR of the mean free path in mm on the texel grid "
                        "(R, G, B or Y; resampled if another size; 0 = no subsurface at that texel). The albedo "
                        "stays the demo's diffuse albedo map (default: none)")
    p.add_argument("--mfp-scale", type=float, default=1.0,
                   help="multiply the mean free path of --subsurface by this factor (default: 1)")
    p.add_argument("--eta", type=float, default=None,
                   help="relative index of refraction of the subsurface Fresnel transmittances (default: the "
                        "preset's, 1.4 for a map)")
    add_out(p, "capture folder to write")
    finish_parser(p, run)


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


def run(args) -> int:
    at_least("--resolution", args.resolution, 2)
    at_least("--image-size", args.image_size, MIN_IMAGE_SIZE)
    out = Path(args.out)
    sensor = _noise(args.noise, args.read_noise)
    sss_source = _mfp_source(args)
    if sss_source is not None and args.space == "image":
        raise CLIError(f"--subsurface {args.subsurface}: texel space only (--space texel): the diffusion operator "
                       "couples texels over the whole surface, which a camera-space capture does not sample")
    if out.exists() and not (out.is_dir() and (not any(out.iterdir()) or (out / "capture.json").is_file())):
        raise CLIError(f"--out {out}: exists and is not a capture folder (or an empty folder); refusing to replace it")
    if args.space == "image":
        return _run_image(args, out, sensor)
    times = {}
    t0 = time.perf_counter()
    spec = mesh_from_args(args)
    mesh, full = texel_surface(spec, args.resolution, where=str(spec["path"]))
    rig, rig_desc = parse_rig(args.rig, args.rig_units, args.rig_up)
    warn_mesh_size("simulate", mesh, rig)
    cams = parse_cameras(args.camera, mesh, args.image_size)
    times["geometry_s"] = time.perf_counter() - t0

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

    rho, f0, alpha = demo_material(surface)
    truth = brdf.lambert_ggx(rho, f0, alpha)
    sss, mfp, model, sss_info = None, None, None, None
    if sss_source is not None:
        t0 = time.perf_counter()
        kind, source, eta = sss_source
        with bar(None, "subsurface (diffusion operator)", args.quiet) as b:
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
    t0 = time.perf_counter()
    with bar(rig.num_lights * len(cams), "simulate (lights)", args.quiet) as b:
        capture = stage.simulate(surface, rig, cams, truth, light_vis, cam_vis, subsurface=sss, progress=b)
    if sensor is not None:
        capture = stage.sense(capture, sensor, jax.random.PRNGKey(args.seed))
    times["simulate_s"] = time.perf_counter() - t0

    # Store on the full texel grid: every light image is a texture (viewable in
    # any EXR viewer); texels without a seen sample are 0 and marked invalid.
    H, W = full.resolution
    V, L, _, C = capture.radiance.shape
    idx = np.asarray(surface.texel_index)
    radiance = np.zeros((V, L, H * W, C), np.float32)
    valid = np.zeros((V, L, H * W), bool)
    radiance[:, :, idx] = np.maximum(np.asarray(capture.radiance, np.float32), 0.0)
    valid[:, :, idx] = np.asarray(capture.mask)
    surf_info = {**spec, "resolution": [H, W]}
    noise = None if sensor is None else {"model": "poisson-gaussian", "exposure": float(args.noise),
                                         "read_noise": args.read_noise, "seed": args.seed}
    material = ("relight demo skin (Lambert + GGX, F0 0.028, alpha 0.2-0.5), ground truth in truth/"
                if sss is None else
                "relight demo skin (GGX, F0 0.028, alpha 0.2-0.5, + subsurface scattering: Burley profile of albedo "
                "rho_d and the mean free path of metadata.subsurface), ground truth in truth/")
    metadata = {"space": "texel", "surface": surf_info, "rig": rig_desc, "material": material,
                "subsurface": sss_info, "noise": noise,
                "units": {"lengths": "mm", "radiance": "relative to the rig's irradiance"},
                "writer": "relight simulate"}
    if out.is_dir() and not any(out.iterdir()):
        out.rmdir()  # an empty folder may be replaced by the capture
    out.parent.mkdir(parents=True, exist_ok=True)  # --out is created, as in every command
    t0 = time.perf_counter()
    write_capture(out, radiance, rig, cams, valid=valid, metadata=metadata, sample_shape=(H, W), half=args.half)
    truth_meta = {"source": "relight simulate ground truth"}
    if sss_info is not None:
        truth_meta["subsurface"] = {"eta": sss_info["eta"], "source": sss_info["source"]}
    write_maps(out / "truth", material_maps(surface, rho, f0, alpha, mfp=mfp, model=model), surface,
               surface_info=spec, metadata=truth_meta)
    # Preview: view 0 with every light on at once.
    all_on = radiance[0].sum(axis=0).reshape(H, W, C)
    covered = np.zeros((H, W), bool)
    covered.reshape(-1)[idx] = True
    view = texture_view(mesh, cams[0], {"all_lights": dilate(all_on, covered)})["all_lights"]
    write_exr(out / "preview_all_lights.exr", view)
    write_preview(out / "preview_all_lights.png", view)
    times["write_s"] = time.perf_counter() - t0
    write_settings(out, "simulate", args, mesh=surf_info, rig=rig_desc, lights=rig.num_lights, views=len(cams),
                   samples_seen=int(len(seen)), texels=[H, W], subsurface=sss_info,
                   timings_s={k: round(v, 3) for k, v in times.items()})
    if not args.quiet:
        tail = "" if sss_info is None else (f", subsurface {sss_info['source']}: mfp "
                                            + "/".join(f"{x:.3g}" for x in sss_info["mfp_mm"]) + " mm (R/G/B)")
        print(f"wrote {out}/ ({V} view(s) x {L} lights, {len(seen)} of {H}x{W} texels seen{tail})")
    return 0


def _run_image(args, out: Path, sensor) -> int:
    """``--space image``: per camera, one sample per pixel (``stage.image_samples``),
    visibility, ``stage.simulate`` and the images [L, H, W, C] (0 off the
    mesh), written as a photo capture (``relight.io.write_photo_capture``) with
    each camera's mask (the pixels that see the mesh)."""
    from ..io import is_photo_capture

    if out.exists() and any(out.iterdir()) and not is_photo_capture(out):
        raise CLIError(f"--out {out}: exists and is not a photo capture (or an empty folder); refusing to replace it")
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
    out.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    write_photo_capture(out, images, rig, cams, half=args.half, masks=masks, metadata=metadata)
    all_on = images[0].sum(axis=0)
    write_exr(out / "preview_all_lights.exr", all_on)
    write_preview(out / "preview_all_lights.png", all_on)
    times["write_s"] = time.perf_counter() - t0
    write_settings(out, "simulate", args, mesh=spec, rig=rig_desc, lights=rig.num_lights, views=len(cams),
                   pixels_seen=[int(m.sum()) for m in masks], timings_s={k: round(v, 3) for k, v in times.items()})
    if not args.quiet:
        print(f"wrote {out}/ ({len(cams)} camera(s) x {rig.num_lights} lights, photo capture)")
    return 0

"""``relight simulate``: render an OLAT capture of a mesh with the demo's
skin-like ground-truth material, and write it as a texel-space capture folder
(``--space texel``) or as a camera-space photo capture (``--space image``: one
image per camera and light, docs/capture_layout.md)."""

from __future__ import annotations

import time
from pathlib import Path

import jax
import numpy as np

import brdf
import stage

from ..image._preview import dilate, texture_view
from ..io import spec_mesh, texel_surface, write_capture, write_exr, write_maps, write_photo_capture
from ..materials._maps import material_maps
from ._common import (
    MIN_IMAGE_SIZE,
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
    add_out(p, "capture folder to write")
    finish_parser(p, run)


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
    t0 = time.perf_counter()
    with bar(rig.num_lights * len(cams), "simulate (lights)", args.quiet) as b:
        capture = stage.simulate(surface, rig, cams, truth, light_vis, cam_vis, progress=b)
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
    metadata = {"space": "texel", "surface": surf_info, "rig": rig_desc,
                "material": "relight demo skin (Lambert + GGX, F0 0.028, alpha 0.2-0.5), ground truth in truth/",
                "noise": noise, "units": {"lengths": "mm", "radiance": "relative to the rig's irradiance"},
                "writer": "relight simulate"}
    if out.is_dir() and not any(out.iterdir()):
        out.rmdir()  # an empty folder may be replaced by the capture
    out.parent.mkdir(parents=True, exist_ok=True)  # --out is created, as in every command
    t0 = time.perf_counter()
    write_capture(out, radiance, rig, cams, valid=valid, metadata=metadata, sample_shape=(H, W), half=args.half)
    write_maps(out / "truth", material_maps(surface, rho, f0, alpha), surface, surface_info=spec,
               metadata={"source": "relight simulate ground truth"})
    # Preview: view 0 with every light on at once.
    all_on = radiance[0].sum(axis=0).reshape(H, W, C)
    covered = np.zeros((H, W), bool)
    covered.reshape(-1)[idx] = True
    view = texture_view(mesh, cams[0], {"all_lights": dilate(all_on, covered)})["all_lights"]
    write_exr(out / "preview_all_lights.exr", view)
    write_preview(out / "preview_all_lights.png", view)
    times["write_s"] = time.perf_counter() - t0
    write_settings(out, "simulate", args, mesh=surf_info, rig=rig_desc, lights=rig.num_lights, views=len(cams),
                   samples_seen=int(len(seen)), texels=[H, W], timings_s={k: round(v, 3) for k, v in times.items()})
    if not args.quiet:
        print(f"wrote {out}/ ({V} view(s) x {L} lights, {len(seen)} of {H}x{W} texels seen)")
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

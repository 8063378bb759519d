"""``relight render``: relight a capture folder (image-based, Debevec et al.
2000), a camera-space photo capture (image-based, each camera's own view;
docs/capture_layout.md) or a fitted map set (model-based,
``relight.render.render_view``) under an environment map, from a camera,
optionally as a turntable of rotations.

A map set whose model map has subsurface texels (``relight fit
--subsurface``, or a simulated capture's truth/) is rendered with the
subsurface term (``relight.render``: Jensen et al. 2001 eq. 5 through the
diffusion operator on the map set's texels), with the eta the set records
(maps.json metadata.subsurface.eta; 1.4 if none)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

import stage

from ..io import write_exr
from ..materials._maps import SUBSURFACE
from ..render._methods import METHODS
from ._common import (
    MIN_IMAGE_SIZE,
    CLIError,
    add_envmap,
    add_image_size,
    add_out,
    add_rig_file_flags,
    at_least,
    auto_exposure,
    bar,
    check_out,
    envmap_path,
    finish_parser,
    output_set,
    parse_cameras,
    parse_rig,
    write_preview,
    write_settings,
    writing,
)

# "rig": the environment seen through a light rig's lights (Debevec et al. 2000)
# -- the only method for a capture (its own OLAT images), and for a map set the
# model rendered under the same rig (relight.render's default). The others need a map set.


def add_parser(sub) -> None:
    p = sub.add_parser("render", help="relight a capture (image-based) or a fitted map set (model-based)",
                       description="Relight INPUT under --envmap: a capture folder is relit image-based (a weighted "
                                   "sum of its one-light images, Debevec et al. 2000); a photo capture "
                                   "(docs/capture_layout.md) the same way, each camera's own view, no geometry; a "
                                   "fitted map set (from "
                                   "`relight fit`) is rendered model-based with relight.render.render_view.")
    p.add_argument("input", metavar="INPUT",
                   help="capture folder (capture.json: texel-space or a photo capture) or fitted map set (maps.json)")
    add_envmap(p)
    add_out(p, "output folder")
    p.add_argument("--method", default="rig", choices=METHODS,
                   help="rig (default: the environment through a light rig; for a capture its own OLAT images, the "
                        "only choice) | dense | fast | reference (model-based, map sets only)")
    p.add_argument("--rig", default=None,
                   help="lsx | dome:N | rig.json: the rig of --method rig for a map set (default: the rig of the "
                        "capture the maps were fitted from)")
    p.add_argument("--camera", default=None,
                   help="front | cameras.json (default: the capture's first camera / the one the maps were "
                        "fitted from)")
    add_rig_file_flags(p)
    add_image_size(p)
    p.add_argument("--rotate", type=float, default=0.0, help="rotate the environment about +y by DEG degrees")
    p.add_argument("--frames", type=int, default=1, help="a turntable of N environment rotations over 360 degrees")
    finish_parser(p, run)


def input_kind(path: Path) -> str:
    from ..io import is_map_set

    if not path.exists():
        raise FileNotFoundError(f"{path}: no such input folder")
    if not path.is_dir():
        raise CLIError(f"{path}: INPUT must be a folder (a capture or a fitted map set)")
    if (path / "capture.json").is_file():
        from ..io import is_photo_capture

        return "photos" if is_photo_capture(path) else "capture"
    if (path / "maps.json").is_file():
        if not is_map_set(path):
            raise CLIError(f"{path / 'maps.json'}: not a relight map set (format is not 'relight-maps')")
        return "maps"
    raise CLIError(f"{path}: neither a capture folder (no capture.json) nor a fitted map set (no maps.json)")


def _angles(rotate: float, frames: int) -> np.ndarray:
    return rotate + 360.0 * np.arange(frames) / frames


def run(args) -> int:
    from ..envmap import load_envmap

    at_least("--frames", args.frames, 1)
    at_least("--image-size", args.image_size, MIN_IMAGE_SIZE)
    src = Path(args.input)
    kind = input_kind(src)
    if kind == "photos":
        return _run_photos(src, args)
    if kind == "capture" and args.method != "rig":
        raise CLIError(f"--method {args.method}: a capture folder is relit image-based; only --method rig applies "
                       f"(model-based methods {', '.join(METHODS[1:])} need a fitted map set)")
    if kind == "capture" and args.rig is not None:
        raise CLIError(f"--rig {args.rig}: a capture is relit with its own rig; --rig applies to map sets")
    if kind == "capture" and (args.rig_units or args.rig_up):
        raise CLIError("--rig-units / --rig-up: a texel-space capture's rig.json is in mm, y up; they apply to photo "
                       "captures and --rig files")
    if args.rig is not None and args.method != "rig":
        raise CLIError(f"--rig {args.rig}: only --method rig uses a rig")
    envmap = envmap_path(args.envmap)
    env = load_envmap(envmap)
    angles = _angles(args.rotate, args.frames)
    check_out(args.out, "render")  # before the work; output_set checks again with the folder locked
    with output_set(args.out, "render", args.quiet) as tmp:
        return _render(src, kind, env, envmap, angles, args, Path(args.out), tmp)


def _render(src: Path, kind: str, env, envmap: Path, angles, args, out: Path, tmp: Path) -> int:
    """Relight ``src`` (a capture or a map set) and write the frames and settings.json into ``tmp``, the
    result set that becomes ``out``."""
    t0 = time.perf_counter()
    subsurface = None
    if kind == "capture":
        frames, camera, method = _image_based(src, env, angles, args)
    else:
        frames, camera, method, subsurface = _model_based(src, env, angles, args)
    seconds = time.perf_counter() - t0
    bad = [k for k, f in enumerate(frames) if not np.all(np.isfinite(f))]
    if bad:
        raise CLIError(f"{src}: frame(s) {bad} came out with NaN or Inf pixels; nothing was written")
    # One exposure for the whole turntable, so frames are comparable.
    exposure = auto_exposure(np.stack(frames))
    names = ["relit"] if len(frames) == 1 else [f"relit_{k:03d}" for k in range(len(frames))]
    # settings.json first: a value JSON refuses stops the run before any image is written.
    write_settings(tmp, "render", args, input_kind=kind, envmap=str(envmap), method=method,
                   rotations_deg=angles.tolist(), camera=stage.camera_to_dict(camera),
                   preview_exposure_stops=exposure, seconds=round(seconds, 3), subsurface=subsurface,
                   outputs=[f"{n}.exr" for n in names])
    for name, img in zip(names, frames, strict=True):
        with writing(tmp / f"{name}.exr"):
            write_exr(tmp / f"{name}.exr", img)
        write_preview(tmp / f"{name}.png", img, exposure=exposure)
    if not args.quiet:
        tail = "" if subsurface is None else (f", subsurface on {subsurface['samples']} texels "
                                              f"(eta {subsurface['eta']:g})")
        print(f"wrote {out}/ ({len(frames)} frame(s), {kind}, method {method}{tail})")
    return 0


def _rotations(angles) -> np.ndarray:
    """[K, 3, 3] rotations of the environment about +y by ``angles`` (degrees)."""
    from ..envmap import rotation_matrix

    return np.stack([np.asarray(rotation_matrix(np.array([0.0, 1.0, 0.0]), np.deg2rad(a)), np.float64)
                     for a in angles])


def _image_based(src: Path, env, angles, args):
    """Relight the capture's texel radiance and show it through ``--camera``
    (``relight.render.image_based_view``: each texel from the nearest captured
    view that sees it)."""
    from ..io import load_texel_capture
    from ..render import image_based_view

    with bar(None, "read capture (images)", args.quiet) as b:
        capture, surface, mesh, _ = load_texel_capture(src, progress=b)
    camera = parse_cameras(args.camera, mesh, args.image_size, default=capture.cameras[:1])[0]
    with bar(len(angles), "render (frames)", args.quiet) as b:
        frames = image_based_view(capture, surface, mesh, camera, env, rotations=_rotations(angles),
                                  progress=b)
    return list(frames), camera, "rig (the capture's own OLAT images)"


def _model_based(src: Path, env, angles, args):
    from ..envmap import rotation_matrix
    from ..io import load_texel_maps

    try:
        from ..render import render_view
    except ImportError as err:
        raise CLIError(f"{src}: model-based rendering needs relight.render.render_view, which this build lacks "
                       f"({err})") from None
    textures, maps, surface, mesh, recorded_cams, recorded_rig = load_texel_maps(src)
    camera = parse_cameras(args.camera, mesh, args.image_size, default=recorded_cams[:1] or None)[0]
    settings = {}
    subsurface = _subsurface_settings(src, textures, maps)
    if subsurface is not None:
        settings["eta"] = subsurface["eta"]
    rig_desc = None
    if args.method == "rig":
        if args.rig is not None:
            settings["rig"], rig_desc = parse_rig(args.rig, args.rig_units, args.rig_up)
        elif recorded_rig is not None:
            settings["rig"] = recorded_rig
            rig_desc = f"the capture's rig ({src / textures.info['metadata']['rig']})"
    frames = []
    with bar(len(angles), "render (frames)", args.quiet) as b:
        for a in angles:
            rot = None
            if a % 360.0 != 0.0:
                rot = np.asarray(rotation_matrix(np.array([0.0, 1.0, 0.0]), np.deg2rad(a)), np.float64)
            img = render_view(maps, surface, mesh, camera, env, method=args.method,
                              progress=None if args.quiet else b, rotation=rot, **settings)
            frames.append(np.asarray(img, np.float32))
            b.update(1)
    return frames, camera, args.method + ("" if rig_desc is None else f" ({rig_desc})"), subsurface


# The subsurface Fresnel transmittances' relative index when a map set records none (relight.render's default).
DEFAULT_ETA = 1.4


def _subsurface_settings(src: Path, textures, maps) -> dict | None:
    """None when no covered texel is on the subsurface rung; else the number of
    subsurface texels, their median mean free path (mm, R/G/B) and eta (from
    maps.json metadata.subsurface.eta, else 1.4)."""
    on = np.asarray(maps.model) == SUBSURFACE
    if not on.any():
        return None
    recorded = (textures.info.get("metadata", {}).get("subsurface") or {}).get("eta")
    try:
        eta = DEFAULT_ETA if recorded is None else float(recorded)
    except (TypeError, ValueError):
        raise CLIError(f"{src / 'maps.json'}: metadata.subsurface.eta must be a number, got {recorded!r}") from None
    if not (np.isfinite(eta) and 1.0 < eta <= 3.0):
        raise CLIError(f"{src / 'maps.json'}: metadata.subsurface.eta must be in (1, 3], got {eta!r}")
    mfp = np.median(np.asarray(maps.mfp, np.float64)[on], axis=0)
    return {"samples": int(on.sum()), "eta": eta, "eta_from": "maps.json" if recorded is not None else "default",
            "mfp_median_mm": mfp.tolist()}


def _run_photos(src: Path, args) -> int:
    """Image-based relighting of a photo capture, camera by camera: each camera's
    photographs [L, H, W, C] summed with the Debevec 2000 weights of the
    capture's rig (``relight.envmap.rotation_sweep_weights``, Voronoi cells;
    ``relight.render.relight_olat_sweep``), no geometry. Writes per camera
    ``<camera>/relit.exr`` (R, G, B, A: A is the coverage) + ``relit.png``, or
    ``relit_000.exr`` ... for a turntable."""
    from ..envmap import load_envmap, rotation_sweep_weights
    from ..io import read_photo_capture

    if args.method != "rig":
        raise CLIError(f"--method {args.method}: a photo capture is relit image-based; only --method rig applies")
    for flag, value in (("--rig", args.rig), ("--camera", args.camera)):
        if value is not None:
            raise CLIError(f"{flag} {value}: a photo capture is relit with its own rig, from its own cameras")
    envmap = envmap_path(args.envmap)
    env = load_envmap(envmap)
    angles = _angles(args.rotate, args.frames)
    t0 = time.perf_counter()
    capture = read_photo_capture(src, rig_units=args.rig_units, rig_up=args.rig_up)
    rig = capture.rig
    weights = rotation_sweep_weights(env, rig.directions, rig.center_irradiance, _rotations(angles))  # [K, L, C]
    # Coverage: the share of each frame's lighting (channel-mean weight) that
    # fell on valid observations (inside the mask, below saturation).
    w_mean = np.mean(np.asarray(weights, np.float64), axis=-1, keepdims=True)  # [K, L, 1]
    total = np.maximum(np.sum(w_mean, axis=1), 1e-30)  # [K, 1]
    check_out(args.out, "render")
    with output_set(args.out, "render", args.quiet) as tmp:
        _relight_photos(capture, rig, weights, w_mean, total, angles, envmap, args, tmp, t0)
    if not args.quiet:
        print(f"wrote {args.out}/ ({capture.n_views} camera(s) x {len(angles)} frame(s), photo capture, method rig)")
    return 0


def _relight_photos(capture, rig, weights, w_mean, total, angles, envmap, args, out: Path, t0: float) -> None:
    """Every camera's relit frames (and previews), then settings.json, into ``out`` (the result set being
    built)."""
    from ..render import relight_olat_sweep

    names = ["relit"] if len(angles) == 1 else [f"relit_{k:03d}" for k in range(len(angles))]
    exposure = None
    outputs = []
    with bar(capture.n_views, "relight (cameras)", args.quiet) as b:
        for v, view in enumerate(capture.iter_views()):
            L, H, W, C = view.radiance.shape
            inside = view.mask.reshape(1, H * W, 1)
            if C != weights.shape[-1] and C != 1:
                raise CLIError(f"{capture.files(v)[0]}: {C} channels, but the rig and the map have "
                               f"{weights.shape[-1]}")
            w = weights if C == weights.shape[-1] else w_mean.astype(np.float32)  # grey photographs: mean weight
            relit = np.asarray(relight_olat_sweep(view.radiance.reshape(L, H * W, C), w))  # [K, P, C]
            lost = np.asarray(relight_olat_sweep((~view.valid).reshape(L, H * W, 1).astype(np.float32),
                                                 w_mean.astype(np.float32)))  # [K, P, 1]: weight on invalid ones
            cover = np.clip(1.0 - lost / total[:, None, :].astype(np.float32), 0.0, 1.0)  # exactly 1 if all valid
            cover = np.where(inside, cover, np.float32(0))
            frames = np.where(inside, relit, np.float32(0)).reshape(-1, H, W, C)
            if exposure is None:  # the first camera's exposure for every camera and frame, so all compare
                exposure = auto_exposure(frames)
            (out / view.name).mkdir(exist_ok=True)
            channels = {1: ["Y", "A"], 3: ["R", "G", "B", "A"]}.get(C, [*(f"C{c}" for c in range(C)), "A"])
            for name, img, cov in zip(names, frames, cover.reshape(-1, H, W, 1), strict=True):
                with writing(out / view.name / f"{name}.exr"):
                    write_exr(out / view.name / f"{name}.exr", np.concatenate([img, cov], axis=-1),
                              channels=channels)
                write_preview(out / view.name / f"{name}.png", img, exposure=exposure)
                outputs.append(f"{view.name}/{name}.exr")
            b.update(1)
    seconds = time.perf_counter() - t0
    write_settings(out, "render", args, input_kind="photos", envmap=str(envmap),
                   method="rig (the photographs' own rig, image-based, per camera)",
                   rig_file=str(capture.rig_file), lights=rig.num_lights, cameras=list(capture.names),
                   rotations_deg=angles.tolist(), preview_exposure_stops=exposure, seconds=round(seconds, 3),
                   outputs=outputs)

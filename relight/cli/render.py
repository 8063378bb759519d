"""``relight render``: relight a capture folder (image-based, Debevec et al.
2000), a camera-space photo capture (image-based, each camera's own view;
docs/capture_layout.md) or a fitted map set (model-based,
``relight.render.render_view``) under an environment map, from a camera,
optionally as a turntable of rotations.

A map set whose model map has subsurface texels (``relight fit
--subsurface``, or a simulated capture's truth/) is rendered with the
subsurface term (``relight.render``: Jensen et al. 2001 eq. 5 through the
diffusion operator on the map set's texels), with the eta the set records
(maps.json metadata.subsurface.eta; 1.4 if none).

Outputs (docs/cli.md): ``relit.exr`` (R, G, B, A: radiance, premultiplied by A,
the fraction of the pixel the subject covers; the run's settings in the
header) and ``relit.png`` (tone-mapped at one exposure for every frame and
camera: ``relight.image.subject_exposure``, metered on the subject alone, or
``--exposure``); ``relit_000.exr`` ... for a turntable; one folder per camera
(``cam000/``, ...) when ``--camera`` holds several."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

# JAX, stage and the library are imported inside the functions that use them, so that ``relight render
# --help`` builds its parser without them (as the other commands do, tests/relight/test_cli_ux.py).
from ._common import (
    INDEX_FRAMES,
    INDEX_SIZE,
    MIN_IMAGE_SIZE,
    CLIError,
    add_envmap,
    add_image_size,
    add_index_flag,
    add_out,
    add_rig_file_flags,
    at_least,
    bar,
    check_out,
    envmap_path,
    finish_parser,
    output_set,
    parse_cameras,
    parse_rig,
    summary,
    write_index_page,
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
                   help="front | cameras.json: every camera in the file, each in its own folder cam000/, ... when "
                        "there are several (default: the capture's first camera / the one the maps were fitted "
                        "from)")
    add_rig_file_flags(p)
    add_image_size(p, what="pixels of the 'front' camera (N x N); with a camera file or the capture's cameras: "
                            "each camera scaled to N pixels on its longer side, its intrinsics with it")
    p.set_defaults(image_size=None)  # None: not given (a camera file's cameras keep their size)
    p.add_argument("--background", default="black", choices=BACKGROUNDS,
                   help="behind the subject: black (default) | env (the rotated environment, composited by "
                        "coverage) | alpha (black in relit.exr, and relit.png with an alpha channel); relit.exr "
                        "always carries the coverage as A")
    p.add_argument("--exposure", type=float, default=None, metavar="EV",
                   help="preview exposure in stops (radiance x 2^EV before the tone curve); default: auto, the "
                        "subject's median luminance to 0.35 (relight.image.subject_exposure), background ignored")
    p.add_argument("--rotate", type=float, default=0.0, help="rotate the environment about +y by DEG degrees")
    p.add_argument("--frames", type=int, default=1, help="a turntable of N environment rotations over 360 degrees")
    add_index_flag(p)
    finish_parser(p, run)


# relight.render.METHODS, spelled here so that building the parser imports no JAX (checked against the
# library's in tests/relight/test_cli_render_outputs.py).
METHODS = ("rig", "dense", "fast", "reference", "lights")
BACKGROUNDS = ("black", "env", "alpha")
# The 'front' camera's pixels (N x N) without --image-size.
FRONT_SIZE = 256


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
    if args.image_size is not None:
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
    """Relight ``src`` (a capture or a map set) from every camera and write the frames, their previews and
    settings.json into ``tmp``, the result set that becomes ``out``."""
    import stage

    from ..image import subject_exposure

    t0 = time.perf_counter()
    subsurface = None
    source = {}  # what index.html's sweep relights: the capture, or the maps with their renderer settings
    if kind == "capture":
        views, cameras, method, mesh = _image_based(src, env, angles, args, source)
    else:
        views, cameras, method, subsurface, mesh = _model_based(src, env, angles, args, source)
    seconds = time.perf_counter() - t0
    for k, (frames, _, _) in enumerate(views):
        bad = [i for i, f in enumerate(frames) if not np.all(np.isfinite(f))]
        if bad:
            where = "" if len(views) == 1 else f" (camera {k})"
            raise CLIError(f"{src}: frame(s) {bad}{where} came out with NaN or Inf pixels; nothing was written")
    # One exposure for every frame and camera, so they compare; metered on the subject, not the background.
    exposure = args.exposure
    if exposure is None:
        C = views[0][0][0].shape[-1]
        exposure = subject_exposure(np.concatenate([f.reshape(-1, C) for fr, _, _ in views for f in fr])[None],
                                    np.concatenate([np.broadcast_to(cov, f.shape[:-1]).reshape(-1)
                                                    for fr, cov, _ in views for f in fr])[None])
    names = ["relit"] if len(angles) == 1 else [f"relit_{k:03d}" for k in range(len(angles))]
    folders = [""] if len(cameras) == 1 else [f"cam{k:03d}/" for k in range(len(cameras))]
    outputs = [f"{d}{n}.exr" for d in folders for n in names]
    unseen = [u for _, _, u in views]
    # settings.json first: a value JSON refuses stops the run before any image is written.
    cam_docs = [stage.camera_to_dict(c) for c in cameras]
    write_settings(tmp, "render", args, input_kind=kind, envmap=str(envmap), method=method,
                   rotations_deg=angles.tolist(), camera=cam_docs[0] if len(cameras) == 1 else None,
                   cameras=cam_docs, camera_folders=None if len(cameras) == 1 else [d[:-1] for d in folders],
                   image_size=[[c.width, c.height] for c in cameras], background=args.background,
                   preview_exposure_stops=exposure,
                   exposure_from="--exposure" if args.exposure is not None else "subject median luminance",
                   unseen_pixel_fraction=unseen, seconds=round(seconds, 3), subsurface=subsurface, outputs=outputs)
    _warn_unseen(kind, unseen, cameras)
    for folder, camera, doc, (frames, cov, _) in zip(folders, cameras, cam_docs, views, strict=True):
        if folder:
            (tmp / folder).mkdir(exist_ok=True)
        for name, angle, img in zip(names, angles, frames, strict=True):
            rgb = img
            if args.background == "env":
                rgb = img + _behind(env, mesh, camera, angle)
            header = {"relight:command": "relight render", "relight:input": str(src),
                      "relight:input_kind": kind, "relight:envmap": str(envmap),
                      "relight:rotation_deg": float(angle), "relight:camera": doc, "relight:method": method,
                      "relight:background": args.background, "relight:preview_exposure_stops": float(exposure),
                      "relight:alpha": "coverage: fraction of the pixel the subject covers; RGB premultiplied"}
            path = tmp / f"{folder}{name}.exr"
            with writing(path):
                write_exr(path, np.concatenate([rgb, cov[..., None]], axis=-1).astype(np.float32),
                          channels=_channels(rgb.shape[-1]), header=header)
            _preview(tmp / f"{folder}{name}.png", rgb, cov, exposure, args.background == "alpha")
    if not args.no_index:
        write_index_page(tmp, lambda: _index_sweeps(tmp, source, env, cameras[0], angles, exposure, names, folders,
                                                    method), "render", args.quiet, location=out)
    if summary(args):
        tail = "" if subsurface is None else (f", subsurface on {subsurface['samples']} texels "
                                              f"(eta {subsurface['eta']:g})")
        cams = "" if len(cameras) == 1 else f" x {len(cameras)} cameras"
        print(f"wrote {out}/ ({len(angles)} frame(s){cams}, {kind}, method {method}{tail})")
    return 0


def _index_sweeps(tmp: Path, source: dict, env, camera, angles, exposure: float, names, folders, method: str):
    """index.html's slider: a turntable's own frames (the first camera's PNGs), else a sweep of the input from
    the first camera at the render's exposure: a capture relit image-based; a map set's own capture relit
    image-based when it is at hand (memory speed), else the maps model-based with the render's method."""
    from ..view import capture_sweep, frames_sweep, map_set_capture, map_set_sweeps, maps_sweep

    if len(angles) > 1:
        return [frames_sweep([tmp / f"{folders[0]}{n}.png" for n in names], angles,
                             f"rendered turntable, method {method}")], None
    if "capture" in source:
        return [capture_sweep(source["capture"], source["surface"], source["mesh"], camera, env, INDEX_FRAMES,
                              INDEX_SIZE, "the capture relit image-based", exposure)], None
    settings = dict(source["settings"])
    rig = settings.pop("rig", None)
    if map_set_capture(source["folder"]) is not None:
        rows, note = map_set_sweeps(source["folder"], env, INDEX_FRAMES, INDEX_SIZE, camera, exposure, model=False,
                                    rig=rig)
        if rows:
            return rows, note
    # Monte Carlo per frame would cost more than the render itself: the quadrature instead.
    sweep_method = "dense" if source["method"] == "reference" else source["method"]
    return [maps_sweep(source["maps"], source["surface"], source["mesh"], camera, env, rig=rig,
                       method=sweep_method, frames=INDEX_FRAMES, size=INDEX_SIZE, exposure=exposure,
                       label=f"the maps rendered model-based, method {sweep_method}", **settings)], None


def write_exr(path, image, **kw) -> None:
    """``relight.io.write_exr`` (imported when first written; a module-level name, which tests replace to
    simulate a full disk)."""
    from ..io import write_exr as _write_exr

    _write_exr(path, image, **kw)


def _channels(C: int) -> list[str]:
    """EXR channel names of a relit image with C colour channels and its coverage A."""
    return {1: ["Y", "A"], 3: ["R", "G", "B", "A"]}.get(C, [*(f"C{c}" for c in range(C)), "A"])


def _behind(env, mesh, camera, angle: float) -> np.ndarray:
    """The environment behind the subject in frame ``angle`` (degrees about +y), to add to its radiance."""
    from ..render import environment_behind

    rot = None if angle % 360.0 == 0.0 else _rotations([angle])[0]
    return environment_behind(env, mesh, camera, rotation=rot)


def _preview(path: Path, rgb: np.ndarray, cov: np.ndarray, exposure: float, alpha: bool) -> None:
    """relit.png: ``rgb`` tone-mapped at ``exposure``; with ``alpha``, RGBA, the colour unpremultiplied
    (PNG's alpha is straight) and A the coverage."""
    if not alpha:
        write_preview(path, rgb, exposure=exposure)
        return
    from ..image import to_uint8, tonemap
    from ..io import write_png

    straight = np.where(cov[..., None] > 0, rgb / np.maximum(cov[..., None], 1e-6), 0.0).astype(np.float32)
    if straight.shape[-1] != 3:
        straight = np.repeat(straight.mean(-1, keepdims=True), 3, -1)
    rgba = np.concatenate([to_uint8(tonemap(straight, exposure=exposure, curve="filmic")), to_uint8(cov[..., None])],
                          axis=-1)
    with writing(path):
        write_png(path, rgba)


def _warn_unseen(kind: str, unseen: list, cameras) -> None:
    """A warning on stderr per camera where some of the subject's pixels lie on texels without data (black:
    a capture camera never saw them, or the map set holds no fitted sample there)."""
    import sys

    why = "no capture camera saw" if kind == "capture" else "the map set holds no fitted sample on"
    for k, u in enumerate(unseen):
        if u is not None and u >= UNSEEN_WARN:
            cam = "" if len(cameras) == 1 else f" (camera {k})"
            print(f"relight render: warning{cam}: {100 * u:.1f}% of the subject's pixels lie on texels {why}; "
                  "they are black in relit.exr (no data there)", file=sys.stderr)


# Fraction of the subject's pixels on texels without data from which render warns (one pixel in a thousand:
# below that, silhouette pixels whose rays graze the texel grid's gutter).
UNSEEN_WARN = 1e-3


def _rotations(angles) -> np.ndarray:
    """[K, 3, 3] rotations of the environment about +y by ``angles`` (degrees)."""
    from ..envmap import rotation_matrix

    return np.stack([np.asarray(rotation_matrix(np.array([0.0, 1.0, 0.0]), np.deg2rad(a)), np.float64)
                     for a in angles])


def scaled_camera(camera, size: int):
    """``camera`` resampled to ``size`` pixels on its longer side: width and height scaled (rounded, aspect
    kept), the intrinsics' rows scaled by the same factors (fx, skew, cx by the width's; fy, cy by the
    height's), so every pixel sees the same part of the scene at the new size. The pose is unchanged."""
    import jax.numpy as jnp

    import stage

    s = size / max(camera.width, camera.height)
    w, h = max(1, round(camera.width * s)), max(1, round(camera.height * s))
    if (w, h) == (camera.width, camera.height):
        return camera
    scale = np.diag([w / camera.width, h / camera.height, 1.0])
    K = jnp.asarray(scale @ np.asarray(camera.K, np.float64), camera.K.dtype)
    return stage.Camera(K=K, R=camera.R, t=camera.t, width=w, height=h, orthographic=camera.orthographic)


def _cameras(args, mesh, default) -> tuple:
    """The render cameras: ``--camera`` (front, or every camera of a camera file) else ``default``; with
    ``--image-size``, each non-front camera scaled to it (:func:`scaled_camera`)."""
    front = args.camera == "front" or (args.camera is None and default is None)
    cams = parse_cameras(args.camera, mesh, FRONT_SIZE if args.image_size is None else args.image_size,
                         default=default)
    if args.image_size is not None and not front:
        cams = tuple(scaled_camera(c, args.image_size) for c in cams)
    return cams


def _image_based(src: Path, env, angles, args, source: dict):
    """Relight the capture's texel radiance and show it through every ``--camera``
    (``relight.render.image_based_view``: each texel from the nearest captured
    view that sees it). Returns, per camera, (frames, coverage, unseen pixel fraction)."""
    from ..io import load_texel_capture
    from ..render import image_based_view, pixel_coverage, seen_texels, texel_fraction, uncovered_fraction

    with bar(None, "read capture (images)", args.quiet) as b:
        capture, surface, mesh, _ = load_texel_capture(src, progress=b)
    cameras = _cameras(args, mesh, capture.cameras[:1])
    source.update(capture=capture, surface=surface, mesh=mesh)
    seen, held = seen_texels(capture, surface)
    views = []
    with bar(len(angles) * len(cameras), "render (frames)", args.quiet) as b:
        for camera in cameras:
            frames = image_based_view(capture, surface, mesh, camera, env, rotations=_rotations(angles))
            cov = pixel_coverage(mesh, camera)
            unseen = uncovered_fraction(cov, texel_fraction(mesh, camera, seen, valid=held))
            views.append((list(frames), cov, unseen))
            b.update(len(angles))
    return views, cameras, "rig (the capture's own OLAT images)", mesh


def _map_set_rig(src: Path, textures, args):
    """(rig, description) for --method rig of a map set: ``--rig``, else the set's rig.json, else the rig.json
    of the capture folder the set records (maps.json metadata.capture, absolute or relative to the set);
    CLIError when there is none (the library's default, the Light Stage X, is not the capture's rig)."""
    import stage

    if args.rig is not None:
        return parse_rig(args.rig, args.rig_units, args.rig_up)
    meta = textures.info.get("metadata", {}) or {}
    own = src / str(meta["rig"]) if meta.get("rig") else None
    if own is not None and own.is_file():
        return stage.load_rig(own), f"the capture's rig ({own})"
    cap = meta.get("capture")
    if isinstance(cap, str) and cap:
        rig = src / cap / "rig.json"  # an absolute path stays as it is; a relative one is the map set's
        if rig.is_file():
            return stage.load_rig(rig), f"the rig of the capture it came from ({rig})"
    raise CLIError(f"{src}: --method rig needs the rig the maps were captured under, and this map set has no "
                   "rig.json (nor records a capture folder holding one); pass --rig <capture>/rig.json (or lsx | "
                   "dome:N), or render with a method that needs no rig (--method dense)")


def _model_based(src: Path, env, angles, args, source: dict):
    from ..envmap import rotation_matrix
    from ..io import load_texel_maps

    try:
        from ..render import pixel_coverage, render_view, texel_fraction, uncovered_fraction
    except ImportError as err:
        raise CLIError(f"{src}: model-based rendering needs relight.render.render_view, which this build lacks "
                       f"({err})") from None
    textures, maps, surface, mesh, recorded_cams, _ = load_texel_maps(src)
    cameras = _cameras(args, mesh, recorded_cams[:1] or None)
    settings = {}
    subsurface = _subsurface_settings(src, textures, maps)
    if subsurface is not None:
        settings["eta"] = subsurface["eta"]
    rig_desc = None
    if args.method == "rig":
        settings["rig"], rig_desc = _map_set_rig(src, textures, args)
    source.update(maps=maps, surface=surface, mesh=mesh, method=args.method, settings=settings, folder=src)
    views = []
    with bar(len(angles) * len(cameras), "render (frames)", args.quiet) as b:
        for camera in cameras:
            frames = []
            for a in angles:
                rot = None
                if a % 360.0 != 0.0:
                    rot = np.asarray(rotation_matrix(np.array([0.0, 1.0, 0.0]), np.deg2rad(a)), np.float64)
                img = render_view(maps, surface, mesh, camera, env, method=args.method, background=False,
                                  progress=None if args.quiet else b, rotation=rot, **settings)
                frames.append(np.asarray(img, np.float32))
                b.update(1)
            cov = pixel_coverage(mesh, camera)
            views.append((frames, cov, uncovered_fraction(cov, texel_fraction(mesh, camera, textures.coverage))))
    method = args.method + ("" if rig_desc is None else f" ({rig_desc})")
    return views, cameras, method, subsurface, mesh


# The subsurface Fresnel transmittances' relative index when a map set records none (relight.render's default).
DEFAULT_ETA = 1.4


def _subsurface_settings(src: Path, textures, maps) -> dict | None:
    """None when no covered texel is on the subsurface rung; else the number of
    subsurface texels, their median mean free path (mm, R/G/B) and eta (from
    maps.json metadata.subsurface.eta, else 1.4)."""
    from ..materials._maps import SUBSURFACE

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
    for flag, value in (("--rig", args.rig), ("--camera", args.camera), ("--image-size", args.image_size)):
        if value is not None:
            raise CLIError(f"{flag} {value}: a photo capture is relit with its own rig, from its own cameras, at "
                           "its photographs' size")
    if args.background == "env":
        raise CLIError("--background env: a photo capture has no geometry to tell the subject from the "
                       "background by; relit.exr's A (the lighting coverage) is 0 outside its masks")
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
        exposure = _relight_photos(capture, rig, weights, w_mean, total, angles, envmap, args, tmp, t0)
        if not args.no_index:
            write_index_page(tmp, lambda: _photo_index_sweeps(tmp, capture, env, angles, exposure), "render",
                             args.quiet, location=Path(args.out))
    if summary(args):
        print(f"wrote {args.out}/ ({capture.n_views} camera(s) x {len(angles)} frame(s), photo capture, method rig)")
    return 0


def _photo_index_sweeps(tmp: Path, capture, env, angles, exposure: float):
    """index.html's slider of a photo capture's render: its turntable frames (the first camera's), else the
    first camera's photographs relit under a sweep of rotations at the render's exposure."""
    from ..view import frames_sweep, photo_sweep

    view = next(capture.iter_views())
    if len(angles) > 1:
        return [frames_sweep([tmp / view.name / f"relit_{k:03d}.png" for k in range(len(angles))], angles,
                             f"rendered turntable of {view.name}")], None
    return [photo_sweep(view.radiance, view.mask, capture.rig, env, INDEX_FRAMES,
                        f"photographs of {view.name} relit image-based", exposure)], None


def _relight_photos(capture, rig, weights, w_mean, total, angles, envmap, args, out: Path, t0: float) -> float:
    """Every camera's relit frames (and previews), then settings.json, into ``out`` (the result set being
    built). Returns the previews' exposure."""
    from ..image import subject_exposure
    from ..render import relight_olat_sweep

    names = ["relit"] if len(angles) == 1 else [f"relit_{k:03d}" for k in range(len(angles))]
    exposure = args.exposure
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
            if exposure is None:  # the first camera's subject exposure for every camera and frame, so all compare
                exposure = subject_exposure(frames, view.mask.reshape(1, H, W).astype(np.float32))
            (out / view.name).mkdir(exist_ok=True)
            channels = _channels(C)
            for name, img, cov in zip(names, frames, cover.reshape(-1, H, W, 1), strict=True):
                with writing(out / view.name / f"{name}.exr"):
                    write_exr(out / view.name / f"{name}.exr", np.concatenate([img, cov], axis=-1),
                              channels=channels)
                _preview(out / view.name / f"{name}.png", img, cov[..., 0], exposure, args.background == "alpha")
                outputs.append(f"{view.name}/{name}.exr")
            b.update(1)
    seconds = time.perf_counter() - t0
    write_settings(out, "render", args, input_kind="photos", envmap=str(envmap),
                   method="rig (the photographs' own rig, image-based, per camera)",
                   rig_file=str(capture.rig_file), lights=rig.num_lights, cameras=list(capture.names),
                   rotations_deg=angles.tolist(), preview_exposure_stops=exposure, seconds=round(seconds, 3),
                   outputs=outputs)
    return exposure

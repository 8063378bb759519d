"""``relight render``: relight a capture folder (image-based, Debevec et al.
2000) or a fitted map set (model-based, ``relight.render.render_view``) under
an environment map, from a camera, optionally as a turntable of rotations."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

import stage

from ..io import write_exr
from ..render._methods import METHODS
from ._common import (
    MIN_IMAGE_SIZE,
    CLIError,
    add_envmap,
    add_image_size,
    add_out,
    at_least,
    auto_exposure,
    bar,
    ensure_out,
    envmap_path,
    finish_parser,
    parse_cameras,
    parse_rig,
    write_preview,
    write_settings,
)

# "rig": the environment seen through a light rig's lights (Debevec et al. 2000)
# -- the only method for a capture (its own OLAT images), and for a map set the
# model rendered under the same rig (relight.render's default). The others need a map set.


def add_parser(sub) -> None:
    p = sub.add_parser("render", help="relight a capture (image-based) or a fitted map set (model-based)",
                       description="Relight INPUT under --envmap: a capture folder is relit image-based (a weighted "
                                   "sum of its one-light images, Debevec et al. 2000); a fitted map set (from "
                                   "`relight fit`) is rendered model-based with relight.render.render_view.")
    p.add_argument("input", metavar="INPUT", help="capture folder (capture.json) or fitted map set (maps.json)")
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
        return "capture"
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
    if kind == "capture" and args.method != "rig":
        raise CLIError(f"--method {args.method}: a capture folder is relit image-based; only --method rig applies "
                       f"(model-based methods {', '.join(METHODS[1:])} need a fitted map set)")
    if kind == "capture" and args.rig is not None:
        raise CLIError(f"--rig {args.rig}: a capture is relit with its own rig; --rig applies to map sets")
    if args.rig is not None and args.method != "rig":
        raise CLIError(f"--rig {args.rig}: only --method rig uses a rig")
    envmap = envmap_path(args.envmap)
    env = load_envmap(envmap)
    angles = _angles(args.rotate, args.frames)
    t0 = time.perf_counter()
    if kind == "capture":
        frames, camera, method = _image_based(src, env, angles, args)
    else:
        frames, camera, method = _model_based(src, env, angles, args)
    seconds = time.perf_counter() - t0
    out = ensure_out(args.out)
    # One exposure for the whole turntable, so frames are comparable.
    exposure = auto_exposure(np.stack(frames))
    names = ["relit"] if len(frames) == 1 else [f"relit_{k:03d}" for k in range(len(frames))]
    for name, img in zip(names, frames, strict=True):
        write_exr(out / f"{name}.exr", img)
        write_preview(out / f"{name}.png", img, exposure=exposure)
    write_settings(out, "render", args, input_kind=kind, envmap=str(envmap), method=method,
                   rotations_deg=angles.tolist(), camera=stage.camera_to_dict(camera),
                   preview_exposure_stops=exposure, seconds=round(seconds, 3),
                   outputs=[f"{n}.exr" for n in names])
    if not args.quiet:
        print(f"wrote {out}/ ({len(frames)} frame(s), {kind}, method {method})")
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
    rig_desc = None
    if args.method == "rig":
        if args.rig is not None:
            settings["rig"], rig_desc = parse_rig(args.rig)
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
    return frames, camera, args.method + ("" if rig_desc is None else f" ({rig_desc})")

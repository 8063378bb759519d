"""``relight render``: relight a capture folder (image-based, Debevec et al.
2000), a camera-space photo capture (image-based, each camera's own view;
docs/capture_layout.md) or a fitted map set (model-based,
``relight.render.render_view``) under an environment map, from a camera,
optionally as a turntable of rotations.

The work is ``relight.render.render_folder`` (docs/cli.md shows the Python);
this module parses the flags, checks their combinations, and writes the
result set (settings.json, index.html) around that one call.

Outputs (docs/cli.md): ``relit.exr`` (R, G, B, A: radiance, premultiplied by A,
the fraction of the pixel the subject covers; the run's settings in the
header) and ``relit.png`` (tone-mapped at one exposure for every frame and
camera: ``relight.image.subject_exposure``, metered on the subject alone, or
``--exposure``); ``relit_000.exr`` ... for a turntable; one folder per camera
(``cam000/``, ...) when ``--camera`` holds several."""

from __future__ import annotations

import sys
from pathlib import Path

# The library is imported inside run(), so that ``relight render --help`` builds its parser without JAX (as
# the other commands do, tests/relight/test_cli_ux.py).
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
    parse_rig,
    summary,
    write_index_page,
    write_settings,
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


# relight.render.METHODS and relight.render.BACKGROUNDS, spelled here so that building the parser imports no JAX
# (checked against the library's in tests/relight/test_cli_render_outputs.py).
METHODS = ("rig", "dense", "fast", "reference", "lights")
BACKGROUNDS = ("black", "env", "alpha")


def _check_flags(args, kind: str) -> None:
    """The flag combinations each input kind takes (CLIError naming the flag)."""
    if kind == "photos":
        if args.method != "rig":
            raise CLIError(f"--method {args.method}: a photo capture is relit image-based; only --method rig applies")
        for flag, value in (("--rig", args.rig), ("--camera", args.camera), ("--image-size", args.image_size)):
            if value is not None:
                raise CLIError(f"{flag} {value}: a photo capture is relit with its own rig, from its own cameras, at "
                               "its photographs' size")
        if args.background == "env":
            raise CLIError("--background env: a photo capture has no geometry to tell the subject from the "
                           "background by; relit.exr's A (the lighting coverage) is 0 outside its masks")
        return
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


def run(args) -> int:
    import numpy as np

    from ..render import input_kind, method_from_name, render_folder
    from ..view import render_sweeps

    at_least("--frames", args.frames, 1)
    if args.image_size is not None:
        at_least("--image-size", args.image_size, MIN_IMAGE_SIZE)
    src = Path(args.input)
    kind = input_kind(src)
    _check_flags(args, kind)
    rig, rig_desc = (None, None) if args.rig is None else parse_rig(args.rig, args.rig_units, args.rig_up)
    method = method_from_name(args.method, **({} if rig is None else {"rig": rig}))
    envmap = envmap_path(args.envmap)
    angles = args.rotate + 360.0 * np.arange(args.frames) / args.frames
    out = Path(args.out)
    check_out(out, "render")  # before the work; output_set checks again with the folder locked
    with output_set(out, "render", args.quiet) as tmp:
        with bar(None, "render", args.quiet) as b:
            done = render_folder(src, envmap, tmp, angles_deg=angles, method=method, rig_description=rig_desc,
                                 camera=args.camera, image_size=args.image_size, background=args.background,
                                 exposure=args.exposure, rig_units=args.rig_units, rig_up=args.rig_up, progress=b)
        write_settings(tmp, "render", args, **done.resolved)
        for line in done.warnings:
            print(f"relight render: {line}", file=sys.stderr)
        if not args.no_index:
            write_index_page(tmp, lambda: render_sweeps(done, envmap, INDEX_FRAMES, INDEX_SIZE), "render",
                             args.quiet, location=out)
    if summary(args):
        print(f"wrote {out}/ {done.summary}")
    return 0

"""The flags several commands take, spelled, typed and explained once (docs/cli.md's table); each command adds
the ones it uses, in its own order, with its own help text where the meaning differs. Building a parser from
this module imports no JAX (tests/relight/test_cli_ux.py)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._guard import CLIError, guarded

# stage.POSITION_UNITS and stage.AXES (the rig-file flags' choices), spelled here so that building a parser
# imports no JAX; tests/relight/test_cli_ux.py checks them against stage's.
RIG_UNITS = ("mm", "cm", "m", "directions")
RIG_AXES = ("+x", "-x", "+y", "-y", "+z", "-z")

# Smallest --image-size: a 'front' camera below 8 x 8 pixels frames nothing useful.
MIN_IMAGE_SIZE = 8

# relight.image.PREVIEW_MIN_PX (texel-space previews are enlarged to at least this many pixels a side), spelled
# here so that building a parser imports no JAX; tests/relight/test_cli_ux.py checks it against the library's.
PREVIEW_MIN_PX = 256

# The sweep of the index.html a command writes into its output: fewer, smaller frames than `relight view`'s, so
# that the page adds little to the command's time (`relight view OUT` makes a finer one).
INDEX_FRAMES = 12
INDEX_SIZE = 128


def add_out(p: argparse.ArgumentParser, help: str, default: str | None = None) -> None:
    """``--out``: the output folder (required unless the command has a ``default``)."""
    p.add_argument("--out", required=default is None, default=default, help=help)


def add_envmap(p: argparse.ArgumentParser, what: str = "lat-long environment map (.hdr/.exr/.pfm)") -> None:
    """``--envmap``: a map file, the bundled one when absent (:func:`envmap_path`)."""
    p.add_argument("--envmap", default=None, help=f"{what}; default: bundled")


def envmap_path(arg: str | None) -> Path:
    """``--envmap``: the given file, or the bundled map."""
    from ..envmap import bundled_envmap_path

    return Path(arg) if arg else bundled_envmap_path()


def add_image_size(p: argparse.ArgumentParser, default: int = 256, what: str = "pixels of the 'front' camera") -> None:
    """``--image-size N``: N x N pixels (at least ``MIN_IMAGE_SIZE``, checked by :func:`at_least`)."""
    p.add_argument("--image-size", type=int, default=default, help=f"{what} (default: {default})")


def finish_parser(p: argparse.ArgumentParser, run) -> None:
    """What every working command ends with: ``--quiet`` and the function that runs it."""
    p.add_argument("-q", "--quiet", action="count", default=0,
                   help="no progress bars; twice (-qq): no summary line either (warnings and errors still show)")
    p.set_defaults(func=guarded(run))


# The largest value of each size or count flag, checked (by :func:`at_least`) before anything is allocated: a
# typo of a few zeros ends in one line naming the flag, not in minutes of work and an out-of-memory kill
# (docs/reliability.md, "Sizes and counts"). Texel grid side 8192: a 64 M-texel map set, 8K being the largest
# texture a face pipeline delivers; image side 16384: stage.MAX_CAMERA_PIXELS; 64 cameras: the most any
# multi-view stage has; 720 frames: a turntable every half degree; 8 BRDF / subsurface alternations: the fit
# settles in 2 (docs/RESULTS.md); a 4096 px viewer sweep.
LIMITS = {"--resolution": 8192, "--image-size": 16384, "--cameras": 64, "--frames": 720, "--passes": 8,
          "--size": 4096}


def at_least(flag: str, value: int, minimum: int) -> None:
    """Refuse an integer flag below ``minimum`` or above its stated limit (``LIMITS``): a CLIError naming the
    flag, the value and the bound."""
    if value < minimum:
        raise CLIError(f"{flag} {value}: must be at least {minimum}")
    if flag in LIMITS and value > LIMITS[flag]:
        raise CLIError(f"{flag} {value}: must be at most {LIMITS[flag]} (relight.cli's stated limit)")


def add_index_flag(p: argparse.ArgumentParser) -> None:
    """``--no-index``: no index.html (the results viewer page, ``relight view``) in the output folder."""
    p.add_argument("--no-index", action="store_true",
                   help="do not write index.html, the results viewer (its rotation sweep costs about a second "
                        "at small sizes); `relight view OUT` writes it later")


def add_mesh_flags(p: argparse.ArgumentParser,
                   what: str = "mesh with UVs (.obj/.ply/.glb); default: the bundled head scan") -> None:
    """``--mesh`` with its placement: ``--units`` or ``--scale``, and ``--center``."""
    p.add_argument("--mesh", default=None, help=f"{what} (a copy of the head scan's file is placed like it)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--units", default=None, choices=("mm", "cm", "m"),
                   help="length unit of the mesh file (default: mm)")
    g.add_argument("--scale", type=float, default=None, help="millimetres per mesh-file unit (instead of --units)")
    p.add_argument("--center", default=None, action=argparse.BooleanOptionalAction,
                   help="move the mesh's bounding-box centre to the rig centre (default: no, except for the head scan)")


def mesh_from_args(args) -> dict:
    """The mesh spec (``relight.io.mesh_spec``) of ``--mesh/--units/--scale/--center``; CLIError on bad values."""
    from ..io import mesh_spec

    try:
        return mesh_spec(args.mesh, units=args.units, scale=args.scale, center=args.center)
    except ValueError as exc:
        raise CLIError(f"--mesh {args.mesh or 'head'}: {exc}") from None


def warn_mesh_size(command: str, mesh, rig) -> None:
    """Print ``relight.io.mesh_size_warning`` on stderr, if any."""
    import sys

    from ..io import mesh_size_warning

    msg = mesh_size_warning(mesh, rig)
    if msg:
        print(f"relight {command}: warning: {msg}", file=sys.stderr)


def add_photo_texel_flags(p: argparse.ArgumentParser, what: str) -> None:
    """How a photo capture is resampled onto a mesh's texel grid: ``--mesh`` and its placement (required),
    ``--resolution``, ``--grazing-deg``, ``--min-views`` (``relight.io.photos_to_texels``), and the rig file's
    ``--rig-units`` / ``--rig-up``. ``what``: to what the flags apply, for the help."""
    add_mesh_flags(p, f"{what} (required; a texel capture records its own): the subject's mesh with UVs, in the "
                      "cameras' frame, or 'head' for the bundled head")
    p.add_argument("--resolution", type=int, default=256, help=f"{what}: texel grid N x N (default 256)")
    p.add_argument("--grazing-deg", type=float, default=80.0,
                   help=f"{what}: drop views more than this far from a texel's normal (default 80)")
    p.add_argument("--min-views", type=int, default=1,
                   help=f"{what}: texels seen by fewer cameras count as unseen (default 1)")
    add_rig_file_flags(p)


def photo_mesh_from_args(args, capture_dir) -> dict:
    """``{"mesh": stage.Mesh, "mesh_info": its spec}`` of a photo capture's ``--mesh`` flags, the other
    :func:`add_photo_texel_flags` checked; CLIError on bad ones."""
    from ..io import spec_mesh

    if args.mesh is None:
        raise CLIError(f"{capture_dir} is a photo capture (camera space): --mesh MESH is needed to resample it onto "
                       "a texel grid (a mesh with UVs in the cameras' frame, mm; 'head' for the bundled head)")
    at_least("--resolution", args.resolution, 1)
    at_least("--min-views", args.min_views, 1)
    if not 0 < args.grazing_deg <= 90:
        raise CLIError(f"--grazing-deg must be in (0, 90], got {args.grazing_deg}")
    try:
        info = mesh_from_args(args)
    except FileNotFoundError as err:
        raise CLIError(f"--mesh: {err}") from None
    return {"mesh": spec_mesh(info, "--mesh"), "mesh_info": info}


def refuse_photo_flags(args, why: str) -> None:
    """CLIError when a flag of :func:`add_photo_texel_flags` that only photo captures take was given."""
    given = [f for f, v in (("--mesh", args.mesh), ("--units", args.units), ("--scale", args.scale),
                            ("--center", args.center), ("--rig-units", args.rig_units), ("--rig-up", args.rig_up))
             if v is not None]
    if given:
        raise CLIError(f"{' / '.join(given)}: {why}")


def add_rig_file_flags(p: argparse.ArgumentParser) -> None:
    """``--rig-units`` / ``--rig-up``: what a rig file does not record (a .npy or
    .txt position table: ``stage.load_rig_file``), or an override of what it does."""
    p.add_argument("--rig-units", default=None, choices=RIG_UNITS,
                   help="unit of the rig file's light positions (mm | cm | m | directions: distant lights); "
                        "needed for .npy/.txt rigs")
    p.add_argument("--rig-up", default=None, choices=(*RIG_AXES, "x", "y", "z"), metavar="AXIS",
                   help="the rig file's axis that points up, +x | -x | +y | -y | +z | -z (write a negative one as "
                        "--rig-up=-y); turned to the stage's +y; needed for .npy/.txt rigs")

"""The ``relight`` command line: ``relight <command> [options]``.

Commands (the same flag names everywhere: ``--out``, ``--envmap``, ``--rig``,
``--camera``, ``--method``, ``--resolution``, ``--quiet``; see docs/cli.md):

* ``simulate``: a texel-space OLAT capture of a mesh into a capture folder;
* ``fit``: reflectance maps from a capture folder (texture set + Mitsuba scene);
* ``render``: relight a capture (image-based) or a map set (model-based);
* ``demo``: simulate, fit and relight the bundled head in one go;
* ``info``: versions, devices and bundled data.

Misuse prints a usage line and exits 2; a bad input file prints
``relight <command>: error: <file>: <problem>`` and exits 1 (no traceback).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from . import fit as _cli_fit

from . import render as _cli_render

from . import simulate as _cli_simulate
from ._common import CLIError


def _cmd_demo(args) -> int:
    from .demo import run_demo
    from ..envmap._latlong import load_envmap

    if args.envmap is not None:
        load_envmap(args.envmap)  # refuse a missing or corrupt map before minutes of simulation and fitting
    report = run_demo(Path(args.out), resolution=args.resolution, envmap=args.envmap,
                      image_size=args.image_size, quiet=args.quiet)
    print(f"wrote {args.out}/ (report.md, report.json, settings.json, *.exr, *.png)")
    print(f"diffuse albedo error (median) {100 * report['diffuse_albedo_rel_error_median']:.3f}%, "
          f"roughness error (median) {100 * report['roughness_rel_error_median']:.3f}%, "
          f"relit PSNR {report['relit_from_fit_vs_image_based_psnr_db']:.1f} dB")
    return 0


def _cmd_info(args) -> int:
    import platform

    import jax

    import stage

    from .demo import bundled_envmap_path

    def version(dist):
        try:
            from importlib.metadata import version as v

            return v(dist)
        except Exception:
            return "not installed"

    print(f"relight {version('lightstage-relight')} (python {platform.python_version()})")
    print("libraries: " + ", ".join(f"{d} {version(d)}" for d in ("jax", "equinox", "optimistix", "numpy", "OpenEXR",
                                                                   "trimesh", "embreex")))
    devices = jax.devices()
    print(f"jax {jax.__version__} on {jax.default_backend()} ({len(devices)} device(s): "
          f"{', '.join(str(d) for d in devices[:4])}{', ...' if len(devices) > 4 else ''})")
    rig = stage.light_stage_x()
    print(f"bundled rig: ICT Light Stage X, {rig.num_lights} lights")
    print(f"bundled mesh: {stage.head_mesh_path()}")
    print(f"bundled environment map: {bundled_envmap_path()}")
    shared = Path(__file__).resolve().parents[2] / "shared" / "data"
    if shared.is_dir():
        entries = sorted(p.name for p in shared.iterdir())
        print(f"shared data: {shared} ({', '.join(entries[:8])}{', ...' if len(entries) > 8 else ''})")
    else:
        print("shared data: none (../shared/data not found)")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="relight", description="Light-stage simulation, reflectance fitting and relighting.")
    sub = p.add_subparsers(dest="command", metavar="<command>")
    _cli_simulate.add_parser(sub)
    _cli_fit.add_parser(sub)
    _cli_render.add_parser(sub)
    d = sub.add_parser("demo", help="simulate, fit and relight the bundled head scan (built-in defaults)")
    d.add_argument("--out", default="relight-demo", help="output folder (default: ./relight-demo)")
    d.add_argument("--resolution", type=int, default=128, help="texel grid size (default: 128)")
    d.add_argument("--envmap", default=None, help="environment map (.hdr/.exr, lat-long); default: bundled Venice Sunset")
    d.add_argument("--image-size", type=int, default=384, help="preview image size in pixels (default: 384)")
    d.add_argument("--quiet", action="store_true", help="no progress bars")
    d.set_defaults(func=_cmd_demo)
    i = sub.add_parser("info", help="versions, devices, bundled data and the shared data folder")
    i.set_defaults(func=_cmd_info)
    return p


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_usage(sys.stderr)
        return 2
    try:
        return args.func(args)
    except (CLIError, OSError, ValueError) as exc:
        # OSError covers FileNotFoundError / FileExistsError / PermissionError;
        # ValueError covers relight.io.ImageFormatError. Messages name the file.
        msg = str(exc) if str(exc) else type(exc).__name__
        if isinstance(exc, OSError) and exc.filename and str(exc.filename) not in msg:
            msg = f"{exc.filename}: {msg}"
        print(f"relight {args.command}: error: {msg}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"relight {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

"""The ``relight`` command line: ``relight <command> [options]``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _cmd_demo(args) -> int:
    from ._demo import run_demo

    report = run_demo(Path(args.out), resolution=args.resolution, envmap=args.envmap,
                      image_size=args.image_size, quiet=args.quiet)
    print(f"wrote {args.out}/ (report.md, report.json, settings.json, *.exr, *.png)")
    print(f"diffuse albedo error (median) {100 * report['diffuse_albedo_rel_error_median']:.3f}%, "
          f"roughness error (median) {100 * report['roughness_rel_error_median']:.3f}%, "
          f"relit PSNR {report['relit_from_fit_vs_image_based_psnr_db']:.1f} dB")
    return 0


def _cmd_info(args) -> int:
    import jax

    import stage

    from ._demo import bundled_envmap_path

    rig = stage.light_stage_x()
    print(f"jax {jax.__version__} on {jax.default_backend()} ({len(jax.devices())} device(s))")
    print(f"bundled rig: ICT Light Stage X, {rig.num_lights} lights")
    print(f"bundled mesh: {stage.head_mesh_path()}")
    print(f"bundled environment map: {bundled_envmap_path()}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="relight", description="Light-stage simulation, reflectance fitting and relighting.")
    sub = p.add_subparsers(dest="command", metavar="<command>")
    d = sub.add_parser("demo", help="simulate, fit and relight the bundled head scan (built-in defaults)")
    d.add_argument("--out", default="relight-demo", help="output folder (default: ./relight-demo)")
    d.add_argument("--resolution", type=int, default=128, help="texel grid size (default: 128)")
    d.add_argument("--envmap", default=None, help="environment map (.hdr/.exr, lat-long); default: bundled Venice Sunset")
    d.add_argument("--image-size", type=int, default=384, help="preview image size in pixels (default: 384)")
    d.add_argument("--quiet", action="store_true", help="no progress bars")
    d.set_defaults(func=_cmd_demo)
    i = sub.add_parser("info", help="versions, devices and bundled data")
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
    except (FileNotFoundError, ValueError) as exc:
        print(f"relight {args.command}: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())

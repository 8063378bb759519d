"""The ``relight`` command line: ``relight <command> [options]``.

Commands (the same flag names everywhere: ``--out``, ``--envmap``, ``--rig``,
``--camera``, ``--method``, ``--resolution``, ``--quiet``; see docs/cli.md):

* ``simulate``: a texel-space OLAT capture of a mesh into a capture folder;
* ``fit``: reflectance maps from a capture folder (texture set + Mitsuba scene);
* ``render``: relight a capture (image-based) or a map set (model-based);
* ``convert``: a capture folder to a chunked Zarr v3 capture store, or back;
* ``demo``: simulate, fit and relight the bundled head in one go;
* ``info``: versions, devices and bundled data.

Misuse prints a usage line and exits 2; a bad input file prints
``relight <command>: error: <file>: <problem>`` and exits 1 (no traceback).

Every command runs with JAX's persistent compilation cache on, in
``--cache-dir DIR``, else ``$RELIGHT_CACHE_DIR``, else
``$XDG_CACHE_HOME/relight/jax`` (``~/.cache/relight/jax``); ``off`` (or an
empty value) turns it off. A second run of a command then loads the solver
programs instead of compiling them (docs/figures/compile_cache.md).
"""

from __future__ import annotations

import argparse
import sys

from . import convert as _cli_convert
from . import demo as _cli_demo
from . import fit as _cli_fit
from . import info as _cli_info
from . import render as _cli_render
from . import simulate as _cli_simulate
from ._common import CLIError, cache_dir, compile_cache

# The commands in the order ``relight --help`` lists them; each module has
# ``add_parser(subparsers)`` and ``run(args)`` and imports no other command.
COMMANDS = (_cli_simulate, _cli_fit, _cli_render, _cli_convert, _cli_demo, _cli_info)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="relight",
                                description="Light-stage simulation, reflectance fitting and relighting.")
    p.add_argument("--cache-dir", default=None, metavar="DIR",
                   help="JAX's persistent compilation cache folder ('off': none); default: $RELIGHT_CACHE_DIR, "
                        "else $XDG_CACHE_HOME/relight/jax (~/.cache/relight/jax)")
    sub = p.add_subparsers(dest="command", metavar="<command>")
    for command in COMMANDS:
        command.add_parser(sub)
    return p


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_usage(sys.stderr)
        return 2
    try:
        # Before the command compiles anything: the cache is looked up at each compile.
        with compile_cache(cache_dir(args.cache_dir), args.command):
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

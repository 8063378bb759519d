"""The ``relight`` command line: ``relight <command> [options]``.

Commands (the same flag names everywhere: ``--out``, ``--envmap``, ``--rig``,
``--camera``, ``--resolution``, ``--quiet``; see docs/cli.md; ``relight --version``):

* ``simulate``: a texel-space OLAT capture of a mesh into a capture folder;
* ``fit``: reflectance maps from a capture folder (texture set + Mitsuba scene);
* ``render``: relight a capture (image-based) or a map set (model-based);
* ``convert``: a capture folder to a chunked Zarr v3 capture store, or back; a photo capture to a texel store;
* ``export``: a fitted map set as binary glTF 2.0 (``--gltf OUT.glb``) for other tools;
* ``demo``: simulate, fit and relight the bundled head in one go;
* ``view``: index.html, the results viewer (a self-contained page with an environment-rotation slider);
* ``reseal``: accept hand edits of a result folder (its manifest rewritten over the files as they now are);
* ``cameras``: a COLMAP, OpenCV or Metashape calibration as the project's camera file;
* ``info``: versions, devices and bundled data, or a photo capture checked before fitting.

``-q`` / ``--quiet`` hides progress bars, ``-qq`` the one-line summary too.
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
import importlib
import os
import sys

# The commands in the order ``relight --help`` lists them, each with its one-line help: the top-level parser is
# built from this table alone, so ``relight --help`` / ``--version`` import no command module (and no JAX); the
# one command named on the line is imported to build its own parser (each module has ``add_parser(subparsers)``
# and ``run(args)`` and imports no other command). tests/relight/test_cli_ux.py checks these lines against the
# modules' own.
COMMANDS = (
    ("simulate", "simulate an OLAT capture of a mesh (texel space) into a capture folder"),
    ("fit", "fit reflectance maps to a capture folder; write a texture set + Mitsuba scene"),
    ("render", "relight a capture (image-based) or a fitted map set (model-based)"),
    ("convert", "capture folder <-> capture store (.zarr, chunked Zarr v3)"),
    ("export", "export a fitted map set as a binary glTF 2.0 file (.glb)"),
    ("demo", "simulate, fit and relight the bundled textured head (built-in defaults)"),
    ("view", "write index.html, the results viewer, into a result folder"),
    ("reseal", "accept hand edits of a result folder (rewrite its manifest)"),
    ("cameras", "import a camera calibration (COLMAP, OpenCV, Metashape) as cameras.json"),
    ("info", "versions, devices, bundled data and the shared data folder"),
)
NAMES = tuple(name for name, _ in COMMANDS)


def version() -> str:
    """The installed ``lightstage-relight`` distribution's version ("unknown" when not installed)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as dist_version

    try:
        return dist_version("lightstage-relight")
    except PackageNotFoundError:
        return "unknown"


def command_module(name: str):
    """``relight.cli.<name>``, imported on demand."""
    return importlib.import_module(f".{name}", __name__)


def _named_command(argv) -> str | None:
    """The command ``argv`` names: its first word that is not an option or ``--cache-dir``'s value."""
    skip = False
    for a in argv:
        if skip:
            skip = False
        elif a == "--cache-dir":
            skip = True
        elif not a.startswith("-"):
            return a if a in NAMES else None
    return None


def build_parser(argv=None, commands=None) -> argparse.ArgumentParser:
    """The ``relight`` parser; the full parser of each command in ``commands`` (default: the one ``argv``
    names; "all": every command), a one-line placeholder for the others."""
    if commands is None:
        named = _named_command(sys.argv[1:] if argv is None else argv)
        commands = () if named is None else (named,)
    elif commands == "all":
        commands = NAMES
    p = argparse.ArgumentParser(prog="relight",
                                description="Light-stage simulation, reflectance fitting and relighting.")
    p.add_argument("--version", action="version", version=f"relight {version()}")
    p.add_argument("--cache-dir", default=None, metavar="DIR",
                   help="JAX's persistent compilation cache folder ('off': none); default: $RELIGHT_CACHE_DIR, "
                        "else $XDG_CACHE_HOME/relight/jax (~/.cache/relight/jax)")
    sub = p.add_subparsers(dest="command", metavar="<command>")
    for name, help in COMMANDS:
        if name in commands:
            command_module(name).add_parser(sub)
        else:
            sub.add_parser(name, help=help, add_help=False)
    return p


def main(argv=None) -> int:
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_usage(sys.stderr)
        return 2
    from ._cache import cache_dir, compile_cache
    from ._guard import CLIError

    try:
        # Before the command compiles anything: the cache is looked up at each compile.
        with compile_cache(cache_dir(args.cache_dir), args.command):
            return args.func(args)
    except BrokenPipeError:
        # The reader of stdout went away (`relight info | head -1`): stop quietly, as a Unix filter does,
        # with stdout pointed at /dev/null so the interpreter's final flush cannot raise again.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141  # 128 + SIGPIPE, what a shell reports for a filter killed by the broken pipe
    except (CLIError, OSError, ValueError) as exc:
        # OSError covers FileNotFoundError / FileExistsError / PermissionError;
        # ValueError covers relight.io.ImageFormatError. Messages name the file.
        msg = str(exc) if str(exc) else type(exc).__name__
        if isinstance(exc, OSError) and exc.filename and str(exc.filename) not in msg:
            msg = f"{exc.filename}: {msg}"
        print(f"relight {args.command}: error: {msg}", file=sys.stderr)
        return 1
    except MemoryError as exc:
        # An allocation beyond this machine's memory (numpy says how much it asked for); the stated limits
        # (docs/reliability.md, "Sizes and counts") bound each input, not their product.
        print(f"relight {args.command}: error: out of memory ({exc or 'no detail'}); lower the sizes asked for "
              "(--resolution, --image-size, lights, cameras, --block)", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"relight {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

"""What every command checks before it runs: a JAX backend that starts, finite float flags; and the one error
type of the command line (:class:`CLIError`)."""

from __future__ import annotations

import os


class CLIError(Exception):
    """A problem with the command line or its inputs: printed as
    ``relight <command>: error: <message>``, exit code 1."""


def _platform_error() -> str | None:
    """None when JAX's backend starts; else one line saying the requested platform is missing and what to do."""
    import jax

    try:
        jax.devices()
    except Exception as err:  # jax raises RuntimeError or a bare AssertionError (JAX_PLATFORMS=cuda on a CPU wheel)
        asked = os.environ.get("JAX_PLATFORMS") or os.environ.get("JAX_PLATFORM_NAME")
        why = f" ({err})" if str(err) else ""
        if asked:
            return (f"JAX_PLATFORMS={asked}: that platform is not available in this JAX install{why}; unset "
                    "JAX_PLATFORMS (or set it to cpu), or install the JAX build for it (pip install 'jax[cuda12]')")
        return f"JAX could not start a backend{why}; set JAX_PLATFORMS=cpu to use the CPU"
    return None


def check_numbers(args) -> None:
    """Refuse a non-finite float flag (nan, inf) before anything is computed or written: CLIError naming it."""
    import math

    for key, value in vars(args).items():
        if isinstance(value, float) and not math.isfinite(value):
            raise CLIError(f"--{key.replace('_', '-')} {value}: must be a finite number")


def guarded(run):
    """``run(args)`` after the checks every command shares: a JAX backend that starts (else one line, exit 2)
    and finite float flags (else a CLIError)."""
    import functools
    import sys

    @functools.wraps(run)
    def wrapper(args) -> int:
        msg = _platform_error()
        if msg is not None:
            print(f"relight {getattr(args, 'command', '')}: error: {msg}", file=sys.stderr)
            return 2
        check_numbers(args)
        return run(args)

    return wrapper

"""JAX's persistent compilation cache while a command runs (``--cache-dir``, ``$RELIGHT_CACHE_DIR``)."""

from __future__ import annotations

import os
from pathlib import Path

# The environment variable naming the cache folder ("" or "off": no cache); --cache-dir overrides it.
CACHE_ENV = "RELIGHT_CACHE_DIR"
# Programs that took at least this long to compile are written to the cache. 0: every program, the
# per-op ones of eager code included (a hit costs ~1 ms to read, a compile 10-50 ms; the solver's take
# seconds). Written before the first compile (main), so nothing compiled by a command escapes it.
CACHE_MIN_COMPILE_S = 0.0


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/relight/jax``, else ``~/.cache/relight/jax``."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "relight" / "jax"


def cache_dir(flag: str | None) -> Path | None:
    """The persistent compilation cache folder: ``--cache-dir`` (``flag``), else ``$RELIGHT_CACHE_DIR``,
    else JAX's own setting (``JAX_COMPILATION_CACHE_DIR``) if any, else :func:`default_cache_dir`; None
    (no cache) when the chosen value is "", "off" or "none"."""
    spec = flag if flag is not None else os.environ.get(CACHE_ENV)
    if spec is None:
        import jax

        own = jax.config.jax_compilation_cache_dir
        return Path(own) if own else default_cache_dir()
    if spec.strip().lower() in ("", "off", "none"):
        return None
    return Path(spec).expanduser()


class compile_cache:
    """Context manager: JAX's persistent compilation cache in ``path`` (None: off) while a command runs
    (``jax_compilation_cache_dir``, ``jax_persistent_cache_min_compile_time_secs`` =
    CACHE_MIN_COMPILE_S, ``jax_persistent_cache_min_entry_size_bytes`` = -1: no size floor), then the
    process's previous settings back (an in-process ``main()`` leaves no global change behind).
    JAX opens its cache once per process, so a change of folder resets it
    (``compilation_cache.reset_cache``). A folder that cannot be made turns the cache off with a warning."""

    _KEYS = ("jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs",
             "jax_persistent_cache_min_entry_size_bytes")

    def __init__(self, path: Path | None, command: str = ""):
        self.path, self.command = path, command

    def _set(self, values: dict) -> None:
        import jax
        from jax.experimental.compilation_cache import compilation_cache as cc

        changed = values["jax_compilation_cache_dir"] != jax.config.jax_compilation_cache_dir
        for k, v in values.items():
            jax.config.update(k, v)
        if changed:
            cc.reset_cache()

    def __enter__(self):
        import jax

        self._old = {k: getattr(jax.config, k) for k in self._KEYS}
        path = self.path
        if path is not None:
            try:
                path.mkdir(parents=True, exist_ok=True)
            except OSError as err:
                import sys

                print(f"relight {self.command}: warning: compilation cache {path}: {err}; running without it",
                      file=sys.stderr)
                path = None
        self._set({"jax_compilation_cache_dir": None if path is None else str(path),
                   "jax_persistent_cache_min_compile_time_secs": CACHE_MIN_COMPILE_S,
                   "jax_persistent_cache_min_entry_size_bytes": -1})
        return self

    def __exit__(self, *exc) -> None:
        self._set(self._old)

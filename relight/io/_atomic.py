"""Atomic file writes for ``relight.io``: a re-export of the one implementation,
``brdf._atomic`` (the lowest package, so ``stage`` and ``brdf`` writers share
it). See that module for the guarantees."""

from brdf._atomic import _final_mode as _final_mode
from brdf._atomic import _umask as _umask
from brdf._atomic import atomic_path as atomic_path
from brdf._atomic import atomic_write_bytes as atomic_write_bytes
from brdf._atomic import atomic_write_text as atomic_write_text

__all__: list[str] = []  # private helpers; the public names are brdf.atomic_path, brdf.atomic_write_*

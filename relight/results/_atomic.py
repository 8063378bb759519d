"""Atomic single-file writes for ``relight``: the public face of the project's
one implementation, ``stage._atomic`` (the lowest package that writes files,
for its rig, camera and pattern files). A temporary file in the destination
folder, flushed to disk, then renamed over the target: a crash leaves the old
file or the new one, never half of one."""

from stage._atomic import _final_mode as _final_mode
from stage._atomic import _umask as _umask
from stage._atomic import atomic_path as atomic_path
from stage._atomic import atomic_write_bytes as atomic_write_bytes
from stage._atomic import atomic_write_text as atomic_write_text

__all__ = ["atomic_path", "atomic_write_bytes", "atomic_write_text"]

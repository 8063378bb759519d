"""Atomic file writes, the project's one implementation: write to a temporary
name in the destination folder, flush it to disk, then ``os.replace`` it over
the target.

Private to ``stage``, whose own file formats (``stage.save_rig``,
``stage.save_cameras``, ``stage.save_patterns``, ``stage.PackedMask.save``) are
written through it, and the lowest package that writes files;
``relight.results`` re-exports it as the public ``relight.results.atomic_path``,
``atomic_write_bytes`` and ``atomic_write_text`` that every ``relight`` writer uses.

Why the same folder: ``os.replace`` is atomic only within one file system, and
a temporary file next to the target is on the same one. A crash (or an
exception in the encoder) therefore leaves either the old file or the new one,
never a half-written file; the temporary file is removed on failure (a
process killed outright leaves it behind, as ``.<name>.*.tmp<suffix>``, but the
target is intact). The final file gets the permissions a plain ``open(path, "w")``
would give it: those of the file it replaces, or 0o666 less the umask.

Folders are a different job (``relight.results.result_set`` swaps a whole
folder into place); this module writes single files only.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import BinaryIO

__all__ = ["atomic_path", "atomic_write_bytes", "atomic_write_text"]


def _umask() -> int:
    """The process's umask, read without changing it where the OS allows
    (/proc/self/status on Linux), else by setting it and restoring it at once."""
    with contextlib.suppress(OSError, ValueError):
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _final_mode(path: Path) -> int:
    """The permission bits ``open(path, "w")`` would leave: those of the file it
    replaces, or 0o666 less the umask for a new file. ``mkstemp`` creates the
    temporary file with 0o600 whatever the umask, so without this every file
    written here would be private to its owner."""
    try:
        return os.stat(path).st_mode & 0o7777
    except FileNotFoundError:
        return 0o666 & ~_umask()


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success, rename it to ``path``.

    The caller writes the whole file to the yielded path (by name, for
    libraries such as OpenEXR that only write to a file name). On an exception
    the temporary file is deleted and the exception propagates; ``path`` is
    untouched. Raises ``FileNotFoundError`` naming the file when its folder
    does not exist.
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise FileNotFoundError(f"{path}: cannot write, folder {folder} does not exist")
    # Keep the real suffix last: some encoders (OpenEXR) look at nothing but
    # the name they are given, and a recognisable suffix helps debugging.
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp" + path.suffix, dir=folder)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        # The mode is set after the caller has written: an encoder that writes
        # by name may have recreated the temporary file.
        os.chmod(tmp_path, _final_mode(path))
        # Flush the bytes before the rename so a power cut cannot expose an
        # empty file under the final name.
        with open(tmp_path, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp_path, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


def atomic_write_bytes(path: str | os.PathLike, write: Callable[[BinaryIO], object]) -> None:
    """Open a temporary binary file next to ``path``, call ``write(fh)``, then rename."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            write(fh)


def atomic_write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> None:
    """Write ``text`` to ``path`` atomically (encoded with ``encoding``)."""
    data = text.encode(encoding)
    atomic_write_bytes(path, lambda fh: fh.write(data))

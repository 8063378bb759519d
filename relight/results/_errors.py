"""The errors of writing result sets and files: each names its folder or file (str() is the message alone),
and a full disk is told as such."""

from __future__ import annotations

import contextlib
import errno
import os
from collections.abc import Iterator
from pathlib import Path

__all__ = ["FolderLockedError", "ForeignFolderError", "NoSpaceError", "ResultSetError", "WriteError",
           "no_space_error", "writing"]

_NO_SPACE = (errno.ENOSPC, errno.EDQUOT)


class ResultSetError(ValueError):
    """A folder that is not a complete, consistent result set: no manifest (an
    interrupted write, or not written by relight), a listed file missing or
    changed (a mix of two writes), or a folder replaced while it was read. A
    ValueError, as every bad input file's error (``relight.io.ImageFormatError``)."""


def edited_hint(folder: str | os.PathLike) -> str:
    """The end of a reader's refusal of a set whose files differ from its manifest: how to accept a deliberate
    edit of ``folder`` (:func:`relight.results.reseal`)."""
    return (f"rerun the command that made it, or, if you edited it on purpose, accept the edit with "
            f"`relight reseal {folder}` (relight.results.reseal)")


class _Named:
    """str() is the message alone: an OSError with ``errno`` / ``filename`` set would print
    ``[Errno N] strerror: 'file'`` instead."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


class FolderLockedError(_Named, OSError):
    """Another live process is writing the output folder."""


class ForeignFolderError(_Named, FileExistsError):
    """The output folder exists and is not a result set of the command's own kind."""


class NoSpaceError(_Named, OSError):
    """The disk (or quota) filled up while a file was written."""


class WriteError(_Named, OSError):
    """A file could not be written (an encoder's failure), naming the file."""


def _err(cls, code: int, msg: str, filename) -> OSError:
    """An OSError subclass whose str() is ``msg`` alone (the three-argument form prints ``[Errno N] ...: 'file'``),
    with ``errno`` and ``filename`` set."""
    e = cls(msg)
    e.errno, e.filename = code, str(filename)  # str() stays msg: the classes are _Named
    return e



def no_space_error(err: OSError, where: str | os.PathLike, exact: bool = False) -> OSError:
    """A full disk's OSError as a :class:`NoSpaceError` that names the file.

    Args:
        err: the OSError raised by a write.
        where: the file (or set) to name when ``err`` names none, or always with ``exact``.
        exact: name ``where`` even when ``err`` names a file (a writer's temporary name).

    Returns:
        A NoSpaceError ("FILE: no space left on device ...") when ``err`` is ENOSPC / EDQUOT, else ``err``.
    """
    if getattr(err, "errno", None) not in _NO_SPACE or isinstance(err, NoSpaceError):
        return err
    name = where if exact or not err.filename else err.filename
    return _err(NoSpaceError, err.errno, f"{name}: no space left on device (nothing was committed; free some space "
                                         "and run again)", name)


@contextlib.contextmanager
def writing(path: str | os.PathLike) -> Iterator[None]:
    """A context in which a failed write names its file.

    ENOSPC / EDQUOT become :class:`NoSpaceError` ("PATH: no space left on device"); an encoder's
    RuntimeError (OpenEXR's bindings raise one when the disk fills) becomes a NoSpaceError when the file
    system has no free block left, else a :class:`WriteError` naming ``path``.

    Args:
        path: the file being written.

    Returns:
        The context manager.
    """
    try:
        yield
    except OSError as err:
        named = no_space_error(err, path, exact=True)  # the file meant, not the writer's temporary name
        if named is err:
            raise
        raise named from err
    except RuntimeError as err:
        folder = Path(path).parent
        try:
            full = os.statvfs(folder if str(folder) else ".").f_bavail == 0
        except OSError:
            full = False
        if full:
            raise no_space_error(OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)), path) from err
        raise _err(WriteError, errno.EIO, f"{path}: cannot write ({err})", path) from err

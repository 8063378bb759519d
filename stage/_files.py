"""The two plain-file readers of the stage's boundary, shared with relight.io:
a JSON document (rig and camera files, capture folders, map sets) and a text
table of light rows (DiLiGenT's ``light_directions.txt`` /
``light_intensities.txt``, Shi et al. 2016). Every error names the file; the
caller picks the ValueError subclass it raises (relight.io's ImageFormatError).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

__all__ = ["existing_path", "parse_json", "read_json", "read_light_table"]


def existing_path(path, what: str, folder: bool = False, error: type[Exception] = ValueError,
                  missing: type[Exception] = FileNotFoundError) -> Path:
    """``path`` as a Path after checking that it is a regular file (links followed) or, with ``folder``, a
    folder: the one rule for every reader of a user's file (stage's calibration readers, relight's image
    readers). A FIFO, a device or a socket is refused by name,
    since reading it would hang (a FIFO) or never end (/dev/zero).

    Args:
        path: the path given by the caller.
        what: what the path should hold, for the messages (e.g. "COLMAP model folder").
        folder: whether a folder is expected instead of a file.
        error: the exception for something of the wrong kind (default ValueError).
        missing: the exception when nothing is there (default FileNotFoundError).

    Returns:
        The path.

    Raises:
        ``missing`` saying "no such {what}" when nothing is there; ``error`` naming what is there instead
        (a file where a folder is expected, a folder, a FIFO, a device, a socket).
    """
    import stat

    path = Path(path)
    if path.is_dir() if folder else path.is_file():
        return path
    try:
        mode = path.stat().st_mode
    except OSError:
        raise missing(f"{path}: no such {what}") from None
    if folder:
        raise error(f"{path}: expected a {what}, got a file")
    kind = ("a folder" if stat.S_ISDIR(mode) else "a FIFO (named pipe)" if stat.S_ISFIFO(mode)
            else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "a socket" if stat.S_ISSOCK(mode)
            else "not a regular file")
    raise error(f"{path}: is {kind}, not a regular file ({what} expected)")


def parse_json(data: str | bytes, where, error: type[ValueError] = ValueError):
    """The JSON document ``data`` (text, or UTF-8 bytes as read from a file), parsed: the one parse of every JSON
    file a user or another run may have written. Raises ``error`` (a ValueError class) naming ``where`` when it is
    not valid JSON or not UTF-8, including the two failures ``json`` does not report as a decode error: an
    integer of more than 4300 digits (ValueError) and nesting deeper than the interpreter's recursion limit
    (RecursionError, which would otherwise escape as a raw traceback)."""
    try:
        return json.loads(data.decode("utf-8") if isinstance(data, bytes) else data)
    except (ValueError, UnicodeDecodeError, RecursionError) as exc:  # JSONDecodeError is a ValueError
        raise error(f"{where}: not valid JSON ({type(exc).__name__}: {str(exc)[:200]})") from None


def read_json(path: str | os.PathLike, what: str = "JSON file", error: type[ValueError] = ValueError):
    """The parsed contents of the JSON file ``path``. Raises FileNotFoundError
    (``what`` says which file was expected) or ``error`` (a ValueError class)
    naming the file when it is not valid JSON (or not UTF-8)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: missing ({what})")
    return parse_json(path.read_bytes(), path, error)


def read_light_table(path: str | os.PathLike, what: str = "light table", cols: int = 3,
                     error: type[ValueError] = ValueError) -> np.ndarray:
    """A whitespace-separated text table of one light per row, ``cols`` numbers
    each (e.g. "x y z" directions, "r g b" intensities), as float64 [L, cols].
    Raises FileNotFoundError, or ``error`` (a ValueError class) naming the file
    and ``what`` when a row does not parse, the table is empty or has another
    width, or a value is NaN or Inf. The meaning of the numbers (unit length,
    positivity, the light count) is the caller's to check."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: missing ({what} file)")
    try:
        table = np.loadtxt(path, dtype=np.float64, ndmin=2)
    except ValueError as exc:
        raise error(f"{path}: {what} must be rows of {cols} numbers ({exc})") from exc
    if table.shape[1] != cols or table.shape[0] == 0:
        raise error(f"{path}: {what} must be rows of {cols} numbers, got shape {table.shape}")
    if not np.all(np.isfinite(table)):
        raise error(f"{path}: {what} contains NaN or Inf")
    return table

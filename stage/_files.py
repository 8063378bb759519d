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

__all__ = ["parse_json", "read_json", "read_light_table"]


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

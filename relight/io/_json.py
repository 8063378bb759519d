"""JSON for relight's files (capture.json, rig.json, cameras.json, maps.json,
settings.json, reports): one conversion of numpy / JAX values to JSON types,
an atomic writer and a reader whose errors name the file."""

from __future__ import annotations

import json
import os
from collections.abc import Mapping

import numpy as np

import stage

from ..results import atomic_write_text
from ._errors import ImageFormatError

__all__ = ["jsonable", "read_json", "write_json"]


def jsonable(obj):
    """``obj`` with numpy / JAX arrays turned into (nested) lists, numpy scalars
    into Python numbers, paths into strings, tuples into lists and mapping keys
    into strings; anything else is returned as it is (``json.dumps`` decides)."""
    if isinstance(obj, Mapping):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray) or hasattr(obj, "__array__"):  # numpy and JAX arrays
        return np.asarray(obj).tolist()
    return obj


def write_json(path: str | os.PathLike, obj, indent: int = 2) -> None:
    """Write ``jsonable(obj)`` to ``path`` atomically (NaN and Inf refused)."""
    atomic_write_text(path, json.dumps(jsonable(obj), indent=indent, allow_nan=False) + "\n")


def read_json(path: str | os.PathLike, what: str = "JSON file"):
    """The parsed contents of a JSON file, read by ``stage.read_json`` (the project's one JSON reader).

    Args:
        path: the file.
        what: which file was expected, for the error of a missing one.

    Returns:
        The parsed document. Raises FileNotFoundError, or :class:`ImageFormatError` (a ValueError) naming the
        file when it is not valid UTF-8 JSON (an integer of more than 4300 digits and nesting deeper than the
        recursion limit included).
    """
    return stage.read_json(path, what, error=ImageFormatError)

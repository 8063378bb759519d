"""Errors raised at the file boundary, and the radiance checks shared by readers.

Every message names the file, the field and what was expected (DESIGN.md,
"Bad input is refused at the boundary").
"""

from __future__ import annotations

import os
from pathlib import Path, PurePosixPath

import numpy as np

__all__ = ["ImageFormatError", "check_radiance", "path_inside"]


class ImageFormatError(ValueError):
    """A file that is not a valid image of the expected format (corrupt,
    truncated, wrong magic, missing channel, inconsistent sizes)."""


def path_inside(folder: str | os.PathLike, rel: object, where: str, *, what: str = "the folder",
                error: type[ValueError] = ImageFormatError) -> Path:
    """``folder / rel`` for a path read from a user's file, refusing what would
    leave ``folder``: a non-string or empty value, an absolute path (POSIX or
    Windows drive), ``..`` components, and links that resolve outside. The
    error (``error``, default :class:`ImageFormatError`) names ``where``."""
    if not isinstance(rel, str) or not rel:
        raise error(f"{where}: must be a relative path inside {what}, got {rel!r}")
    pure = PurePosixPath(rel.replace("\\", "/"))
    if pure.is_absolute() or Path(rel).is_absolute() or ".." in pure.parts or (pure.parts and ":" in pure.parts[0]):
        raise error(f"{where}: path {rel!r} leaves {what} (absolute paths and '..' are refused)")
    folder = Path(folder)
    path = folder / Path(*pure.parts)
    if not path.resolve().is_relative_to(folder.resolve()):
        raise error(f"{where}: path {rel!r} leads outside {what} (through a link)")
    return path


def check_radiance(values: np.ndarray, path: str | os.PathLike, what: str = "radiance") -> None:
    """Refuse NaN, Inf or negative values in an input radiance array.

    Radiance is a non-negative physical quantity (W sr^-1 m^-2, or relative
    units); a NaN or a negative value in a capture or an environment map is a
    broken file or a broken upstream tool, and would silently poison every sum
    (light weights, relighting) downstream. The message gives the count and the
    first offending index so the pixel can be inspected.
    """
    values = np.asarray(values)
    bad_nan = ~np.isfinite(values)
    if bad_nan.any():
        idx = tuple(int(i) for i in np.argwhere(bad_nan)[0])
        raise ImageFormatError(
            f"{path}: {what} has {int(bad_nan.sum())} NaN/Inf values (first at index {idx}); "
            "expected finite, non-negative radiance"
        )
    neg = values < 0
    if neg.any():
        idx = tuple(int(i) for i in np.argwhere(neg)[0])
        raise ImageFormatError(
            f"{path}: {what} has {int(neg.sum())} negative values (first at index {idx}, "
            f"value {float(values[idx]):.6g}); expected non-negative radiance"
        )

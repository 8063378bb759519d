"""Errors raised at the file boundary, and the radiance checks shared by readers.

Every message names the file, the field and what was expected (DESIGN.md,
"Bad input is refused at the boundary").
"""

from __future__ import annotations

import os

import numpy as np

__all__ = ["ImageFormatError", "check_radiance"]


class ImageFormatError(ValueError):
    """A file that is not a valid image of the expected format (corrupt,
    truncated, wrong magic, missing channel, inconsistent sizes)."""


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

"""The MERL binary BRDF writer (Matusik et al. 2003): the inverse of
``brdf.read_merl``, which reads the format for the measured model. File layout:
``brdf._merl``'s docstring (three int32 dimensions, then the three channels of
float64 values, each divided by its scale)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from brdf import MERL_RES, MERL_SCALE

from ..results import atomic_write_bytes

__all__ = ["write_merl"]


def write_merl(path: str | os.PathLike, table) -> None:
    """Write a table of f_r as a MERL ``.binary`` file, atomically.

    Args:
        path: the file to write (a temporary file in the same folder is renamed onto it; the file gets the
            permissions ``open`` would give).
        table: f_r in 1/sr, shape [3, 90, 90, 180] (channel, theta_h, theta_d, phi_d); negative values mark
            missing measurements.

    Returns:
        None. Raises ValueError naming ``path`` for a table of another shape or with NaN / Inf.

    References:
        Matusik, Pfister, Brand and McMillan 2003, "A Data-Driven Reflectance Model" (the MERL database
        and its BRDFRead.cpp file layout).
    """
    path = Path(path)
    t = np.asarray(table, dtype=np.float64)
    if t.shape != (3,) + MERL_RES:
        raise ValueError(f"write_merl({path}): table must have shape (3, 90, 90, 180), got {t.shape}")
    if not np.all(np.isfinite(t)):
        raise ValueError(f"write_merl({path}): table has non-finite values")
    stored = t / np.asarray(MERL_SCALE)[:, None, None, None]

    def write(fh):
        fh.write(np.asarray(MERL_RES, dtype="<i4").tobytes())
        fh.write(stored.astype("<f8").tobytes(order="C"))

    atomic_write_bytes(path, write)

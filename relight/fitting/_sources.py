"""The capture a fit reads, through ``relight.io.CaptureSource``: one read interface for a
``stage.Capture``, a capture store, a capture folder and a ``SampleSubset`` of either."""

from __future__ import annotations

import numpy as np

import stage

from ..io import CaptureSource, capture_source


def open_source(capture, where: str = "fit") -> tuple[CaptureSource, stage.Rig, tuple[stage.Camera, ...]]:
    """(source, rig, cameras) of ``capture`` (``relight.io.capture_source``), checked.

    Raises TypeError naming ``capture`` for anything but a capture or a source, ValueError when it
    has not one camera per view.
    """
    try:
        source = capture_source(capture)
    except TypeError as err:
        raise TypeError(f"{where}: {err}") from None
    rig, cameras = source.stage_rig(), tuple(source.stage_cameras())
    V = int(source.shape[0])
    if len(cameras) != V:
        raise ValueError(f"{where}: capture has {V} views but {len(cameras)} cameras")
    return source, rig, cameras


def read_block(source: CaptureSource, s: int, e: int) -> tuple[np.ndarray, np.ndarray]:
    """(radiance [V, L, e - s, C], mask [V, L, e - s] bool) of samples s..e, as NumPy."""
    rad, mask = source.read(samples=slice(s, e))
    return np.asarray(rad), np.asarray(mask, bool)

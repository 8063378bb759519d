"""What a simulated capture is made of and gives back: the subsurface settings (:class:`MeanFreePath`), the
record of what was written (:class:`SimulatedCapture`), and the metadata both capture forms share."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

import skin_bssrdf

__all__ = ["MeanFreePath", "SimulatedCapture"]

MATERIAL = "relight demo skin (Lambert + GGX, F0 0.028, alpha 0.2-0.5)"
SSS_MATERIAL = ("relight demo skin (GGX, F0 0.028, alpha 0.2-0.5, + subsurface scattering: Burley profile of "
                "albedo rho_d and the mean free path of metadata.subsurface)")
UNITS = {"lengths": "mm", "radiance": "relative to the rig's irradiance"}


@dataclasses.dataclass(frozen=True)
class MeanFreePath:
    """The subsurface scattering of a simulated capture: the diffuse mean free path and the Fresnel eta.

    Args:
        mfp: float [3] (mm per channel, everywhere) or [H, W, 3] (a map on the texture atlas; 0 = no
            subsurface at that texel), as ``relight.io.read_mean_free_path`` gives it.
        eta: the relative index of refraction of the Fresnel transmittances (default ``skin_bssrdf.SKIN_ETA``).
        source: what the mean free path is (recorded: "preset skin1", a file name).
        scale: the factor already applied to ``mfp`` (recorded).

    Returns:
        The settings, for ``simulate_texel_capture(..., subsurface=)``.
    """

    mfp: np.ndarray
    eta: float = skin_bssrdf.SKIN_ETA
    source: str = ""
    scale: float = 1.0


@dataclasses.dataclass(frozen=True)
class SimulatedCapture:
    """What ``simulate_texel_capture`` / ``simulate_photo_capture`` wrote.

    Args:
        path: the capture folder or store.
        resolved: the settings to record (views, lights, samples seen, timings, peak memory, ...).
        summary: one line saying what was written.
        images: the photo capture's images [L, H, W, C] per camera (photo captures only; None otherwise).
        masks: the photo capture's masks [H, W] per camera (photo captures only; None otherwise).

    Returns:
        The record.
    """

    path: Path
    resolved: dict
    summary: str
    images: list | None = None
    masks: list | None = None


def noise_record(sensor, seed: int, sample: str) -> dict | None:
    """The metadata's ``noise`` entry: the sensor model and the key of each observation (None: no sensor)."""
    return None if sensor is None else {
        "model": "poisson-gaussian", "exposure": float(sensor.exposure), "read_noise": float(sensor.read_noise),
        "seed": int(seed), "keys": f"fold_in(fold_in(fold_in(PRNGKey(seed), view), light), {sample})"}

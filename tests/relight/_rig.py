"""Test helpers: the Light Stage X directions from ../shared/data and cached env maps."""

import functools
import json
from pathlib import Path

import numpy as np

from relight.envmap import load_envmap

ENVMAPS = ["grace", "uffizi", "pisa", "ennis", "venice_sunset_1k", "royal_esplanade_1k"]
SMALL_ENVMAPS = ENVMAPS[:4]


def light_stage_x(shared_data: Path) -> np.ndarray:
    """Unit directions [346, 3] from the stage centre to each Light Stage X light."""
    return _lsx(str(shared_data))


@functools.lru_cache(maxsize=2)
def _lsx(folder: str) -> np.ndarray:
    with open(Path(folder) / "lightstage" / "light_stage_x.json") as fh:
        pos = np.asarray(json.load(fh)["positions_cm"], np.float64)
    return pos / np.linalg.norm(pos, axis=1, keepdims=True)


@functools.lru_cache(maxsize=8)
def envmap(shared_data: Path, name: str):
    return load_envmap(Path(shared_data) / "envmaps" / f"{name}.hdr")


def fibonacci_sphere(n: int) -> np.ndarray:
    """n nearly uniform unit vectors (golden-angle spiral)."""
    i = np.arange(n) + 0.5
    y = 1 - 2 * i / n
    r = np.sqrt(1 - y * y)
    phi = np.pi * (1 + 5**0.5) * i
    return np.stack([r * np.cos(phi), y, r * np.sin(phi)], axis=-1)

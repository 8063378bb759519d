"""``Dense``: the midpoint rule over the environment area-resampled to ``rows`` x 2 ``rows`` pixels,
each pixel a distant light with ray-cast visibility (converges to the exact integral as ``rows``
grows)."""

from __future__ import annotations

import math
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..envmap._latlong import latlong_directions, latlong_solid_angles, sample_latlong
from ._abstract import int_at_least
from ._directional import AbstractDirectional
from ._fast import area_resample

__all__ = ["Dense", "DenseLighting"]


class DenseLighting(eqx.Module):
    """``Dense``'s prepared lighting: the area-resampled map ``lowres`` [h, 2h, C], its pixels'
    directions ``dirs`` [2 h^2, 3] (row-major) and solid angles ``dom`` [2 h^2]."""

    lowres: Any
    dirs: np.ndarray
    dom: Any
    dtype: Any = eqx.field(static=True)


def _latlong_dirs_np(h: int) -> np.ndarray:
    """``relight.envmap.latlong_directions(h, 2 h)`` as concrete NumPy [2 h^2, 3] (evaluated at trace
    time, so concrete even under an outer jit / grad)."""
    with jax.ensure_compile_time_eval():
        return np.asarray(latlong_directions(h, 2 * h), np.float64).reshape(-1, 3)


class Dense(AbstractDirectional):
    """The midpoint rule over the environment area-resampled to ``rows`` x 2 ``rows`` pixels.

    Each pixel is a distant light (the area mean of the map over it) with ray-cast visibility; the
    sum converges to the exact integral as ``rows`` grows. Under a rotation about y by whole pixels
    the grid is rolled exactly; other rotations resample it bilinearly.

    Args:
        rows: rows of the quadrature grid (>= 2; the string spelling's keyword ``resolution``).
    """

    rows: int = 32

    name: ClassVar[str] = "dense"
    KEYWORDS: ClassVar[dict[str, str]] = {"resolution": "rows"}

    def __check_init__(self):
        int_at_least("dense", "rows", self.rows, 2, alias="resolution")

    def prepare(self, env, *, dtype=jnp.float32) -> DenseLighting:
        h = self.rows
        return DenseLighting(area_resample(jnp.asarray(env.radiance, dtype), h), _latlong_dirs_np(h),
                             latlong_solid_angles(h, 2 * h, dtype).reshape(-1), dtype)

    def num_directions(self, lighting: DenseLighting) -> int:
        return int(lighting.dirs.shape[0])

    def light_set(self, lighting: DenseLighting, rotation):
        dt = lighting.dtype
        h = lighting.lowres.shape[0]
        low = lighting.lowres
        if rotation is not None:
            r = np.asarray(rotation, np.float64)
            ang = math.atan2(r[0, 2], r[0, 0])
            cols = ang / (2 * math.pi) * (2 * h)
            is_y = np.allclose(r, [[math.cos(ang), 0, math.sin(ang)], [0, 1, 0], [-math.sin(ang), 0, math.cos(ang)]],
                               atol=1e-6)
            if is_y and abs(cols - round(cols)) < 1e-3:
                # A rotation about y by whole pixels is an exact column roll (L_new(d) = L(R^T d)).
                low = jnp.roll(low, int(round(cols)), axis=1)
            else:
                low = sample_latlong(low, latlong_directions(h, 2 * h, dt) @ jnp.asarray(r, dt), "bilinear")
        strength = low.reshape(-1, low.shape[-1]) * lighting.dom[:, None]
        return jnp.asarray(lighting.dirs, dt), strength, False

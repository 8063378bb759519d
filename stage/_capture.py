"""The OLAT capture: what a light stage records, in texel (or pixel) space."""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ._camera import Camera
from ._rig import Rig


class Capture(eqx.Module):
    """One-light-at-a-time radiance ``radiance`` [V, L, P, C] (float32 or
    float16; units of the rig's intensity times sr^-1), a validity ``mask``
    [V, L, P] (True where the sample is lit by the light, unshadowed, seen by
    the camera and unsaturated), the ``rig``, the ``cameras`` (one per view) and
    the ``sensor`` (a ``stage.Sensor``, or None for noise-free radiance) that
    recorded it."""

    radiance: Float[Array, "view light sample channel"]
    mask: Bool[Array, "view light sample"]
    rig: Rig
    cameras: tuple[Camera, ...]
    sensor: Any = None

    def __check_init__(self):
        V, L, P, _ = self.radiance.shape
        if self.mask.shape != (V, L, P):
            raise ValueError(f"Capture.mask must have shape {(V, L, P)}, got {self.mask.shape}")
        if L != self.rig.num_lights:
            raise ValueError(f"Capture has {L} light images but the rig has {self.rig.num_lights} lights")
        if len(self.cameras) != V:
            raise ValueError(f"Capture has {V} views but {len(self.cameras)} cameras")

    @property
    def shape(self) -> tuple[int, int, int, int]:
        return tuple(self.radiance.shape)

    def astype(self, dtype) -> Capture:
        """The capture with its radiance cast to ``dtype`` (float32 or float16)."""
        return eqx.tree_at(lambda c: c.radiance, self, self.radiance.astype(dtype))

    def lights(self, index) -> Capture:
        """The capture restricted to the lights ``index``."""
        index = jnp.asarray(index)
        return Capture(radiance=self.radiance[:, index], mask=self.mask[:, index],
                       rig=self.rig.subset(index), cameras=self.cameras, sensor=self.sensor)

"""``Rig``: the environment sampled at a light rig's lights (Debevec et al. 2000), each light shading
through stage's OLAT forward model with its near-field falloff: what an OLAT capture supports, equal
to ``relight_olat`` of ``stage.simulate`` of the same maps on the same rig."""

from __future__ import annotations

from typing import Any, ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np

import stage

from ..envmap._latlong import EnvMap
from ..envmap._weights import light_weights, light_weights_barycentric
from ._abstract import int_at_least
from ._directional import AbstractDirectional

__all__ = ["Rig", "RigLighting"]


class RigLighting(eqx.Module):
    """``Rig``'s prepared lighting: the ``rig``, its light directions ``dirs`` [L, 3] from the rig
    centre, and the environment ``env`` (the light weights are taken from it per rotation)."""

    rig: stage.Rig
    dirs: np.ndarray
    env: EnvMap
    dtype: Any = eqx.field(static=True)


class Rig(AbstractDirectional):
    """The environment sampled at a light rig's lights with ``relight.envmap.light_weights``.

    Each light shades through stage's OLAT forward model with its near-field falloff: what an OLAT
    capture supports.

    Args:
        rig: a ``stage.Rig`` (None: ``stage.light_stage_x()``).
        weights: "voronoi" (``light_weights``, Voronoi cells) or "barycentric".
        supersample: of the Voronoi weights (>= 1).

    References:
        Debevec et al. 2000, "Acquiring the Reflectance Field of a Human Face", sec. 4.
    """

    rig: stage.Rig | None = None
    weights: str = "voronoi"
    supersample: int = 1

    name: ClassVar[str] = "rig"
    KEYWORDS: ClassVar[dict[str, str]] = {"rig": "rig", "weights": "weights", "supersample": "supersample"}

    def __check_init__(self):
        int_at_least("rig", "supersample", self.supersample, 1)
        if self.weights not in ("voronoi", "barycentric"):
            raise ValueError(f"method 'rig': weights must be 'voronoi' or 'barycentric', got {self.weights!r}")
        if self.rig is not None and not isinstance(self.rig, stage.Rig):
            raise ValueError(f"method 'rig': rig must be a stage.Rig, got {type(self.rig).__name__}")

    def prepare(self, env, *, dtype=jnp.float32) -> RigLighting:
        rig = stage.light_stage_x() if self.rig is None else self.rig
        pos = np.asarray(rig.position, np.float64)
        return RigLighting(rig, pos / np.linalg.norm(pos, axis=1, keepdims=True),
                           EnvMap(jnp.asarray(env.radiance, dtype)), dtype)

    def num_directions(self, lighting: RigLighting) -> int:
        return lighting.rig.num_lights

    def cast_visibility(self, lighting: RigLighting, mesh, surface, terminator: bool):
        return stage.light_visibility(mesh, surface, lighting.rig, packed=True, terminator=terminator)

    def light_set(self, lighting: RigLighting, rotation):
        dt = lighting.dtype
        rig = lighting.rig
        d = jnp.asarray(lighting.dirs, dt)
        d_env = d if rotation is None else d @ jnp.asarray(rotation, dt)
        e = jnp.asarray(rig.center_irradiance, dt)
        if e.shape[-1] == 1:
            e = jnp.broadcast_to(e, (e.shape[0], lighting.env.radiance.shape[-1]))
        if self.weights == "voronoi":
            w = light_weights(lighting.env, d_env, e, supersample=self.supersample).astype(dt)
        else:
            w = light_weights_barycentric(lighting.env, d_env, e).astype(dt)
        # w_l times the light's own strength: intensity (near field, divided by the squared distance
        # in the kernel) or irradiance (distant).
        inten = jnp.asarray(rig.intensity, dt)
        pos = jnp.asarray(rig.position, dt) if rig.near_field else d
        return pos, w * inten, bool(rig.near_field)

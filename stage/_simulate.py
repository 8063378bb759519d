"""OLAT capture simulation: every light of a rig, one at a time, on every
surface sample, as every camera sees it.

L_o(p, wo) = f_r(wi, wo) cos(theta_i) E_l(p) V_l(p) for light l, with E_l the
irradiance at normal incidence (inverse-square for near-field lights) and V_l
the ray-cast visibility (the reflection equation for a point source,
pbrt-v4 eq. 4.14 with a delta light).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import brdf
from brdf import safe_normalize

from ._camera import Camera
from ._capture import Capture
from ._rig import Rig
from ._surface import Surface


def shading_directions(surface: Surface, rig: Rig, camera_center):
    """Local-frame wi [L, P, 3], wo [P, 3] and irradiance at normal incidence [L, P, C]."""
    wi_world, irradiance = rig.incident(surface.position)
    wo_world = safe_normalize(jnp.asarray(camera_center)[None, :] - surface.position)
    return surface.to_local(wi_world), surface.to_local(wo_world), irradiance


@eqx.filter_jit
def _shade_chunk(material: "brdf.AbstractBRDF", wi, wo, irradiance, visible):
    """radiance [Lc, P, C] = f(wi, wo) cos_i E V for a chunk of lights (vmap over lights)."""

    def one_light(wi_l, e_l, v_l):
        f = material(wi_l, wo)
        cos_i = jnp.maximum(wi_l[..., 2:3], 0)
        return jnp.where(v_l[:, None], f * cos_i * e_l, 0)

    return jax.vmap(one_light)(wi, irradiance, visible)


def simulate(surface: Surface, rig: Rig, cameras, material: "brdf.AbstractBRDF", light_visibility,
             camera_visibility, *, light_chunk: int = 64, dtype=jnp.float32, progress=None) -> Capture:
    """Simulate an OLAT capture of ``material`` (a brdf Module whose parameters
    have a leading sample axis [P, ...]) on ``surface`` under ``rig``.

    light_visibility: bool [P, L] (stage.light_visibility); camera_visibility:
    bool [V, P] (stage.camera_visibility). Returns a Capture whose radiance is 0
    where the light is shadowed, and whose mask marks the observations that are
    lit, seen and front-facing. ``progress(n)`` is called after each light chunk.
    """
    cameras = tuple(cameras) if isinstance(cameras, (list, tuple)) else (cameras,)
    if not all(isinstance(c, Camera) for c in cameras) or not cameras:
        raise ValueError("simulate needs at least one stage.Camera")
    P, L = surface.num_samples, rig.num_lights
    lv = np.asarray(light_visibility, dtype=bool)
    cv = np.asarray(camera_visibility, dtype=bool)
    if lv.shape != (P, L):
        raise ValueError(f"light_visibility must have shape [P, L] = {(P, L)}, got {lv.shape}")
    if cv.shape != (len(cameras), P):
        raise ValueError(f"camera_visibility must have shape [V, P] = {(len(cameras), P)}, got {cv.shape}")
    radiance, mask = [], []
    for v, cam in enumerate(cameras):
        wi, wo, irr = shading_directions(surface, rig, cam.center)
        front = np.asarray(wo[:, 2] > 0) & cv[v]
        chunks = []
        for s in range(0, L, light_chunk):
            e = min(s + light_chunk, L)
            vis = jnp.asarray(lv[:, s:e].T & front[None])
            chunks.append(np.asarray(_shade_chunk(material, wi[s:e], wo, irr[s:e], vis)).astype(dtype))
            if progress is not None:
                progress(e - s)
        radiance.append(np.concatenate(chunks, axis=0))
        lit = np.asarray(wi[..., 2] > 0)
        mask.append(lv.T & front[None] & lit)
    return Capture(radiance=jnp.asarray(np.stack(radiance)), mask=jnp.asarray(np.stack(mask)),
                   rig=rig, cameras=cameras)

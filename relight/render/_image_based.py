"""Image-based relighting of a texel-space capture seen through a novel camera
(Debevec et al. 2000, "Acquiring the Reflectance Field of a Human Face", sec. 4:
relit = sum_l w_l OLAT_l, with the weights of :mod:`relight.envmap`).

The relit radiance lives on the capture's texel samples; a render camera sees
it on the mesh (``relight.image.texture_view``). Each texel takes its relit
radiance from the capture view that sees it (under any light) and whose camera
direction, seen from the rig centre, is closest to the render camera's. From a
camera between the captured ones, the view-dependent (specular) part is
therefore that of the nearest captured view: an image-based capture cannot do
better without a reflectance model (for that, fit one: ``relight.fit``).
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Array, Float

import stage

from ..envmap._latlong import EnvMap
from ..envmap._weights import rotation_sweep_weights
from ..image._preview import dilate, texture_view
from ._olat import relight_olat_sweep

__all__ = ["image_based_view", "image_based_weights", "nearest_view", "relight_photographs", "seen_texels"]

# Gutter texels filled around each UV chart before the texture lookup, so the
# bilinear lookup at a chart border does not blend in the empty background
# (relight.image.dilate's default, as the CLI always used).
_DILATE_TEXELS = 2
# Frames looked up per ray cast of the camera: the primary rays are cast once for a group of frames;
# the group bounds the textures held at once.
_FRAMES_PER_CAST = 8


def nearest_view(capture: stage.Capture, camera: stage.Camera) -> np.ndarray:
    """int [P]: per sample, the capture view that sees it (a valid observation
    under any light) from the direction closest to ``camera``'s, both directions
    taken from the rig centre to the camera centres. A sample no view sees gets
    view 0 (its radiance is then masked out anyway)."""

    def unit(c):
        c = np.asarray(c, np.float64)
        return c / max(np.linalg.norm(c), 1e-12)

    target = unit(camera.center)
    score = np.array([unit(c.center) @ target for c in capture.cameras])  # [V]
    seen = np.asarray(capture.mask).any(axis=1)  # [V, P]
    return np.argmax(np.where(seen, score[:, None], -np.inf), axis=0)


def seen_texels(capture: stage.Capture, surface: stage.Surface) -> tuple[np.ndarray, np.ndarray]:
    """(seen, held), bool [H, W] on ``surface``'s texel grid: texels some capture view observes (a valid
    observation under any light), and texels the capture holds a sample of. Relit image-based, a held
    texel no view saw is black (it has no radiance); ``relight.render.texel_fraction`` shows where."""
    seen = np.asarray(capture.mask).any(axis=(0, 1))  # [P]
    H, W = surface.resolution
    idx = np.asarray(surface.texel_index)
    grid_seen, held = np.zeros(H * W, bool), np.zeros(H * W, bool)
    grid_seen[idx[seen]] = True
    held[idx] = True
    return grid_seen.reshape(H, W), held.reshape(H, W)


def image_based_weights(env: EnvMap, rig: stage.Rig, rotations) -> Float[Array, "K L C"]:
    """The light weights of a rig under the environment turned by each rotation.

    Args:
        env: lat-long environment map.
        rig: the capture's rig (its light directions and irradiance at the rig centre).
        rotations: [K, 3, 3] rotations of the environment (light from d arrives from R d).

    Returns:
        [K, L, C] weights: ``relight.envmap.rotation_sweep_weights`` (Voronoi cells of the light
        directions, divided by each light's irradiance at the rig centre).

    References:
        Debevec et al. 2000, "Acquiring the Reflectance Field of a Human Face", sec. 4.
    """
    rots = np.asarray(rotations, np.float64)
    if rots.ndim != 3 or rots.shape[1:] != (3, 3):
        raise ValueError(f"rotations must be [K, 3, 3], got shape {rots.shape}")
    return rotation_sweep_weights(env, rig.directions, rig.center_irradiance, rots)


def image_based_view(capture: stage.Capture, surface: stage.Surface, mesh: stage.Mesh, camera: stage.Camera,
                     env: EnvMap, rotations=None, progress: stage.Progress | None = None) -> np.ndarray:
    """The texel-space ``capture`` relit under ``env`` and seen through ``camera``.

    Args:
        capture: OLAT radiance [V, L, P, C] over ``surface``'s samples (texel
            space: ``surface.texel_index`` places them on its texel grid).
        surface: the capture's texel samples (``stage.texel_samples`` or a subset).
        mesh: the mesh the texel grid belongs to (with UVs), for the view.
        camera: the render camera (any pose: each texel's radiance comes from
            the nearest captured view, :func:`nearest_view`).
        env: lat-long environment map; the weights are :func:`image_based_weights`.
        rotations: optional [K, 3, 3] rotations of the environment (a turntable;
            light from d arrives from R d); default one frame, unrotated.
        progress: optional ``progress(phase, done, total)`` (``stage.Progress``):
            the frames done, phase "image-based relighting".

    Returns:
        float32 [K, H, W, C] frames (K = 1 without ``rotations``), H x W the
        camera's image size; pixels that miss the mesh are 0.

    References:
        Debevec et al. 2000, "Acquiring the Reflectance Field of a Human Face", sec. 4.
    """
    rots = np.eye(3)[None] if rotations is None else np.asarray(rotations, np.float64)
    weights = image_based_weights(env, capture.rig, rots)
    relit = np.asarray(relight_olat_sweep(capture.radiance, weights))  # [K, V, P, C]
    relit = relit[:, nearest_view(capture, camera), np.arange(surface.num_samples)]  # [K, P, C]
    H, W = surface.resolution
    covered = np.zeros((H, W), bool)
    covered.reshape(-1)[np.asarray(surface.texel_index)] = True
    frames = []
    bar = stage.Phase(progress, "image-based relighting", len(rots))
    for k0 in range(0, len(rots), _FRAMES_PER_CAST):
        ks = range(k0, min(k0 + _FRAMES_PER_CAST, len(rots)))
        textures = {str(k): dilate(surface.to_texture(relit[k]), covered, _DILATE_TEXELS) for k in ks}
        views = texture_view(mesh, camera, textures)  # one ray cast for the group of frames
        frames += [views[str(k)] for k in ks]
        bar.advance(len(ks))
    return np.stack(frames).astype(np.float32, copy=False)


def relight_photographs(radiance, mask, weights, valid=None) -> tuple[np.ndarray, np.ndarray]:
    """One camera's photographs relit under K lightings, with each frame's lighting coverage.

    Args:
        radiance: [L, H, W, C] the photographs, one per light.
        mask: bool [H, W], the subject.
        weights: [K, L, Cw] light weights (:func:`image_based_weights`); grey photographs (C = 1)
            take the channel mean of colour weights.
        valid: optional bool [L, H, W], the valid observations (inside the mask, below saturation).

    Returns:
        (frames float32 [K, H, W, C], 0 outside the mask; coverage float32 [K, H, W, 1], the share of
        each frame's lighting (channel-mean weight) that fell on valid observations, 1 where every
        observation is valid, 0 outside the mask).

    References:
        Debevec et al. 2000, "Acquiring the Reflectance Field of a Human Face", sec. 4.
    """
    radiance = np.asarray(radiance)
    L, H, W, C = radiance.shape
    Cw = np.shape(weights)[-1]
    if C != Cw and C != 1:
        raise ValueError(f"{C} channels, but the rig and the map have {Cw}")
    w_mean = np.mean(np.asarray(weights, np.float64), axis=-1, keepdims=True)  # [K, L, 1]
    w = weights if C == Cw else w_mean.astype(np.float32)  # grey photographs: the mean weight
    inside = np.asarray(mask, bool).reshape(1, H * W, 1)
    relit = np.asarray(relight_olat_sweep(radiance.reshape(L, H * W, C), w))  # [K, P, C]
    if valid is None:
        cover = np.ones((len(w_mean), H * W, 1), np.float32)
    else:
        total = np.maximum(np.sum(w_mean, axis=1), 1e-30)  # [K, 1]
        lost = np.asarray(relight_olat_sweep((~np.asarray(valid, bool)).reshape(L, H * W, 1).astype(np.float32),
                                             w_mean.astype(np.float32)))  # [K, P, 1]: weight on invalid ones
        cover = np.clip(1.0 - lost / total[:, None, :].astype(np.float32), 0.0, 1.0)  # exactly 1 if all valid
    cover = np.where(inside, cover, np.float32(0))
    frames = np.where(inside, relit, np.float32(0)).reshape(-1, H, W, C)
    return frames, cover.reshape(-1, H, W, 1)

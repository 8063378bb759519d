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

import stage

from ..envmap._latlong import EnvMap
from ..envmap._weights import rotation_sweep_weights
from ..image._preview import dilate, texture_view
from ._olat import relight_olat_sweep

__all__ = ["image_based_view", "nearest_view", "seen_texels"]

# Gutter texels filled around each UV chart before the texture lookup, so the
# bilinear lookup at a chart border does not blend in the empty background
# (relight.image.dilate's default, as the CLI always used).
_DILATE_TEXELS = 2


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
        env: lat-long environment map; the weights are
            ``relight.envmap.rotation_sweep_weights`` over the capture's rig
            (Voronoi cells of its light directions, divided by each light's
            irradiance at the rig centre).
        rotations: optional [K, 3, 3] rotations of the environment (a turntable;
            light from d arrives from R d); default one frame, unrotated.
        progress: optional ``progress(phase, done, total)`` (``stage.Progress``):
            the frames done, phase "image-based relighting".

    Returns:
        float32 [K, H, W, C] frames (K = 1 without ``rotations``), H x W the
        camera's image size; pixels that miss the mesh are 0.
    """
    rots = np.eye(3)[None] if rotations is None else np.asarray(rotations, np.float64)
    if rots.ndim != 3 or rots.shape[1:] != (3, 3):
        raise ValueError(f"rotations must be [K, 3, 3], got shape {rots.shape}")
    rig = capture.rig
    weights = rotation_sweep_weights(env, rig.directions, rig.center_irradiance, rots)
    relit = np.asarray(relight_olat_sweep(capture.radiance, weights))  # [K, V, P, C]
    relit = relit[:, nearest_view(capture, camera), np.arange(surface.num_samples)]  # [K, P, C]
    H, W = surface.resolution
    covered = np.zeros((H, W), bool)
    covered.reshape(-1)[np.asarray(surface.texel_index)] = True
    frames = []
    bar = stage.Phase(progress, "image-based relighting", len(rots))
    for k in range(len(rots)):
        tex = dilate(surface.to_texture(relit[k]), covered, _DILATE_TEXELS)
        frames.append(texture_view(mesh, camera, {"relit": tex})["relit"])
        bar.advance(1)
    return np.stack(frames).astype(np.float32, copy=False)

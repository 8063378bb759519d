"""What a render camera sees besides the shaded subject: how much of each pixel
the mesh covers (the alpha of a relit image), the environment behind the
subject, and how much of the subject lies on texels that hold data.

Every function casts the render's own sub-pixel rays (``stage.primary_hits``
on the ``supersample`` x ``supersample`` grid that ``render_view`` and
``relight.image.texture_view`` use) and box-filters them down, so the three
line up with the relit radiance pixel for pixel: a composite over the
environment is ``subject + environment_behind`` (the subject premultiplied by
its coverage, as both renderers return it).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

import stage

from ..envmap._latlong import EnvMap, sample_latlong
from ..image._preview import dilate, row_bands, texture_view

__all__ = ["environment_behind", "pixel_coverage", "texel_fraction", "uncovered_fraction", "uncovered_pixels"]

# Gutter texels a texel mask is widened by before its lookup, as the renderers widen their maps
# (relight.render's and relight.image.dilate's two rings), so a chart border is not counted as a gap.
_DILATE_TEXELS = 2
# A pixel is part of the subject when at least half of its sub-pixel rays hit the mesh
# (relight.image.subject_exposure's rule), and on a gap when less than half of its hits land on data.
_HALF = 0.5


def _check(mesh, camera, supersample) -> int:
    if not isinstance(mesh, stage.Mesh):
        raise ValueError(f"mesh must be a stage.Mesh, got {type(mesh).__name__}")
    if not isinstance(camera, stage.Camera):
        raise ValueError(f"camera must be a stage.Camera, got {type(camera).__name__}")
    if not isinstance(supersample, (int, np.integer)) or isinstance(supersample, bool) or supersample < 1:
        raise ValueError(f"supersample must be an integer >= 1, got {supersample!r}")
    return int(supersample)


def _box(x: np.ndarray, camera: stage.Camera, s: int) -> np.ndarray:
    """[H s, W s, ...] sub-pixels -> [H, W, ...] pixels (their mean)."""
    tail = x.shape[2:]
    return x.reshape(camera.height, s, camera.width, s, *tail).mean(axis=(1, 3))


def pixel_coverage(mesh: stage.Mesh, camera: stage.Camera, supersample: int = 2) -> np.ndarray:
    """float32 [H, W] in [0, 1]: the fraction of each pixel's ``supersample``^2 primary rays that hit
    ``mesh`` (the alpha / coverage of a relit image)."""
    s = _check(mesh, camera, supersample)
    occ = stage.Occluder(mesh)
    out = np.empty((camera.height, camera.width), np.float32)
    for r0, band in row_bands(camera, s):
        out[r0:r0 + band.height] = _box(stage.primary_hits(mesh, band, s, occluder=occ)[0].astype(np.float32), band, s)
    return out



def environment_behind(env: EnvMap, mesh: stage.Mesh, camera: stage.Camera, rotation=None,
                       supersample: int = 2) -> np.ndarray:
    """float32 [H, W, C]: the environment seen by the primary rays that miss ``mesh``, box-filtered with
    the hits counted as 0, so ``subject + environment_behind`` is the subject composited over the
    environment (what ``render_view(..., background=True)`` returns). ``rotation`` [3, 3]: light from d
    arrives from R d (the renderers' convention), so a ray d sees the map at R^T d."""
    s = _check(mesh, camera, supersample)
    rot = None
    if rotation is not None:
        rot = np.asarray(rotation, np.float64)
        if rot.shape != (3, 3):
            raise ValueError(f"rotation must be [3, 3], got shape {rot.shape}")
    rad = jnp.asarray(env.radiance)
    occ = stage.Occluder(mesh)
    out = np.empty((camera.height, camera.width, rad.shape[-1]), np.float32)
    for r0, band in row_bands(camera, s):
        hit = stage.primary_hits(mesh, band, s, occluder=occ)[0]
        h, w = hit.shape
        ys, xs = np.meshgrid((np.arange(h) + 0.5) / s, (np.arange(w) + 0.5) / s, indexing="ij")
        _, d = band.rays(jnp.asarray(np.stack([xs, ys], -1).reshape(-1, 2)))
        d = np.broadcast_to(np.asarray(d, np.float64), (h * w, 3))
        if rot is not None:
            d = d @ rot  # row vectors: R^T d
        seen = np.asarray(sample_latlong(rad, jnp.asarray(d, rad.dtype)), np.float32).reshape(h, w, -1)
        seen = np.where(hit[..., None], np.float32(0), seen)
        out[r0:r0 + band.height] = _box(seen, band, s)
    return out


def texel_fraction(mesh: stage.Mesh, camera: stage.Camera, texels, valid=None, supersample: int = 2) -> np.ndarray:
    """float32 [H, W]: the fraction of each pixel's rays that hit ``mesh`` on a texel where ``texels``
    [h, w] (bool, on the mesh's texel grid, row 0 at v = 1) is set: a bilinear lookup of the 0/1 mask,
    as the renderers look their maps up. ``valid`` [h, w]: the texels that hold a value (the others, the
    gutter, are filled from their valid neighbours for two rings first); default: ``texels`` itself."""
    s = _check(mesh, camera, supersample)
    mask = np.asarray(texels, bool)
    if mask.ndim != 2:
        raise ValueError(f"texels must be a [h, w] mask on the texel grid, got shape {mask.shape}")
    valid = mask if valid is None else np.asarray(valid, bool)
    if valid.shape != mask.shape:
        raise ValueError(f"valid must have texels' shape {mask.shape}, got {valid.shape}")
    tex = dilate(mask.astype(np.float32)[..., None], valid, _DILATE_TEXELS)
    return np.clip(texture_view(mesh, camera, {"t": tex}, supersample=s)["t"][..., 0], 0.0, 1.0).astype(np.float32)


def uncovered_pixels(coverage, on_data) -> tuple[int, int]:
    """``(gaps, subject)``: the subject's pixels (``coverage`` >= 0.5) and, of them, those where less than
    half of the subject lies on texels with data (``on_data`` < 0.5 ``coverage``; ``on_data`` from
    :func:`texel_fraction`)."""
    cov = np.asarray(coverage, np.float64)
    on = np.asarray(on_data, np.float64)
    if cov.shape != on.shape:
        raise ValueError(f"coverage {cov.shape} and on_data {on.shape} must have the same shape")
    subject = cov >= _HALF
    return int(np.sum(on[subject] < _HALF * cov[subject])), int(np.sum(subject))


def uncovered_fraction(coverage, on_data) -> float:
    """Of the subject's pixels (``coverage`` >= 0.5), the fraction where less than half of the subject
    lies on texels with data (:func:`uncovered_pixels`). 0.0 when no pixel is the subject's."""
    gaps, subject = uncovered_pixels(coverage, on_data)
    return gaps / subject if subject else 0.0

"""Camera-space photographs to a texel-space OLAT capture.

``photos_to_texels`` resamples a photo capture (docs/capture_layout.md) onto
the texel grid of a mesh's UV atlas, camera by camera, so ``relight.fit`` can
fit it as it fits a simulated texel capture: the result is a
``stage.Capture`` [V, L, P, C] with its validity mask [V, L, P] and the
``stage.Surface`` of the texels, plus a :class:`PhotoTexelReport` saying which
texels no camera sees (never silently black: they have no valid observation,
so the fit flags them, and the report counts and maps them).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

import stage

from ._photos import PhotoCapture

SAMPLING = "bilinear"
# Rejection reasons, in the order they are applied (each counts texels still in the running).
REASONS = stage.PROJECTION_REJECTIONS


@dataclasses.dataclass(frozen=True)
class PhotoTexelReport:
    """What :func:`photos_to_texels` did.

    ``texels``: P, the texels of the grid inside the UV atlas. ``views_per_texel``
    [P] int: cameras that see each texel (in the image, in the camera's mask,
    facing it within ``grazing_deg``, not occluded). ``unseen`` [P] bool: seen by
    fewer than ``min_views`` cameras (all its observations are invalid, so
    ``relight.fit`` flags it); ``n_unseen`` their count. ``coverage`` [H, W]
    int32 on the texel grid: ``views_per_texel``, -1 where the grid has no texel
    (outside the atlas). ``weight`` [V, P] float32: cos theta_o of each seen
    (view, texel), 0 where not seen (a foreshortening weight: a texel seen at
    theta_o covers cos theta_o as many pixels as seen head-on). ``rejected``:
    per view, texel counts per reason (``REASONS``, applied in that order).
    ``valid_fraction`` [V]: share of the seen texels' (light) observations that
    are valid (unsaturated, and lit when ``shadows``).
    """

    texels: int
    views_per_texel: np.ndarray
    unseen: np.ndarray
    coverage: np.ndarray
    weight: np.ndarray
    rejected: tuple[dict, ...]
    valid_fraction: tuple[float, ...]
    names: tuple[str, ...]
    grazing_deg: float
    min_views: int
    shadows: bool
    sampling: str = SAMPLING

    @classmethod
    def of(cls, surface: stage.Surface, weight: np.ndarray, rejected, valid_fraction, names, *, grazing_deg: float,
           min_views: int, shadows: bool) -> PhotoTexelReport:
        """The report of a resampling from its per-view ``weight`` [V, P] (cos theta_o, 0 where unseen):
        the view counts, the unseen texels and the coverage map derive from it."""
        views = np.sum(weight > 0, axis=0).astype(np.int64)
        return cls(texels=surface.num_samples, views_per_texel=views, unseen=views < int(min_views),
                   coverage=surface.to_texture(views.astype(np.int32), fill=np.int32(-1)), weight=weight,
                   rejected=tuple(rejected), valid_fraction=tuple(valid_fraction), names=tuple(names),
                   grazing_deg=float(grazing_deg), min_views=int(min_views), shadows=bool(shadows))

    @property
    def n_unseen(self) -> int:
        return int(np.sum(self.unseen))

    def to_dict(self) -> dict:
        """A JSON-ready summary (no per-texel arrays)."""
        return {"texels": int(self.texels), "unseen": self.n_unseen,
                "unseen_fraction": float(self.n_unseen / max(self.texels, 1)),
                "views_per_texel_histogram": np.bincount(self.views_per_texel, minlength=len(self.names) + 1).tolist(),
                "views": [{"camera": n, "seen": int(np.sum(self.weight[v] > 0)), "rejected": dict(r),
                           "valid_fraction": float(f)}
                          for v, (n, r, f) in enumerate(zip(self.names, self.rejected, self.valid_fraction,
                                                            strict=True))],
                "grazing_deg": float(self.grazing_deg), "min_views": int(self.min_views),
                "shadows": bool(self.shadows), "sampling": self.sampling}


def check_texel_arguments(where: str, grazing_deg: float, min_views: int) -> None:
    """ValueError naming ``grazing_deg`` outside (0, 90] or ``min_views`` below 1."""
    if not 0 < grazing_deg <= 90:
        raise ValueError(f"{where}: grazing_deg must be in (0, 90], got {grazing_deg}")
    if int(min_views) < 1:
        raise ValueError(f"{where}: min_views must be >= 1, got {min_views}")


# Texels per gather in sample_taps: its [L, block, 4, C] temporary stays a few tens of MiB at any grid size.
_TAP_BLOCK = 1 << 16


def sample_taps(rad: np.ndarray, ok_px: np.ndarray, taps: np.ndarray, weights: np.ndarray):
    """Bilinear samples of images at texels: ``rad`` [L, H * W, C] and its validity ``ok_px`` [L, H * W], the
    texels' four pixel indices ``taps`` [n, 4] and bilinear ``weights`` [n, 4]. Returns radiance float32
    [L, n, C] and validity [L, n], valid only where all four taps are (no sample mixes in background or
    clipped pixels). Gathered ``_TAP_BLOCK`` texels at a time, so the taps' temporary does not grow with n."""
    L, n, C = rad.shape[0], len(taps), rad.shape[-1]
    out, ok = np.empty((L, n, C), np.float32), np.empty((L, n), bool)
    w = weights.astype(np.float32)
    for s in range(0, n, _TAP_BLOCK):
        t = taps[s:s + _TAP_BLOCK]
        np.einsum("lnkc,nk->lnc", rad[:, t], w[s:s + _TAP_BLOCK], out=out[:, s:s + _TAP_BLOCK])
        np.all(ok_px[:, t], axis=2, out=ok[:, s:s + _TAP_BLOCK])
    return out, ok


def photos_to_texels(photos: PhotoCapture, mesh: stage.Mesh, resolution: int | tuple[int, int], *,
                     grazing_deg: float = 80.0, min_views: int = 1, shadows: bool = True,
                     progress=None) -> tuple[stage.Capture, stage.Surface, PhotoTexelReport]:
    """Resample a photo capture onto the texel grid of ``mesh`` (its UV atlas at
    ``resolution``, ``stage.texel_samples``).

    For each camera (read one at a time, ``PhotoCapture.read_view``), every
    texel centre is projected (``stage.project_texels``: ``stage.Camera.project``, through the
    camera's lens distortion) and
    rejected when it is behind the camera or its bilinear footprint leaves the
    image, back-facing (n . wo <= 0) or grazing (theta_o > ``grazing_deg``),
    outside the camera's mask (any of its four taps), or occluded (a segment
    to the camera centre meets the mesh: ``stage.camera_visibility``).
    Radiance is sampled **bilinearly** from the four pixels around the
    projection: a texel (1/resolution of the atlas) rarely lands on a pixel
    centre, and nearest sampling would shift it by up to half a pixel. An
    observation (view, light, texel) is valid only when all four taps are
    valid under that light (``PhotoView.valid``: in the mask, unsaturated), so
    no sample mixes in background or clipped pixels; with ``shadows`` (default)
    also only where the texel sees the light (``stage.light_visibility``, as a
    simulated capture's mask: the fitter does not model cast shadows).
    A texel seen by fewer than ``min_views`` cameras gets no valid observation.

    Returns ``(capture, surface, report)``: ``stage.Capture`` radiance float32
    [V, L, P, C] (0 where invalid) and mask [V, L, P], the photo capture's rig
    and cameras, no sensor; the texel ``stage.Surface``; a
    :class:`PhotoTexelReport`. ``progress(phase, done, total)``: phase
    "photos to texels", cameras done of V.
    """
    check_texel_arguments("photos_to_texels", grazing_deg, min_views)
    surface = stage.texel_samples(mesh, resolution)
    P, V, L = surface.num_samples, photos.n_views, photos.n_lights
    lit = np.asarray(stage.light_visibility(mesh, surface, photos.rig), bool).T if shadows else None  # [L, P]
    occluder = stage.Occluder(mesh, surface)  # one BVH for every camera
    bar = stage.Phase(progress, "photos to texels", V)
    radiance = mask = None
    weight = np.zeros((V, P), np.float32)
    rejected, valid_frac = [], []
    for v in range(V):
        view = photos.read_view(v)
        H, W = view.mask.shape
        rad = view.radiance.reshape(L, H * W, -1)
        ok_px = view.valid.reshape(L, H * W)
        if radiance is None:
            radiance = np.zeros((V, L, P, rad.shape[-1]), np.float32)
            mask = np.zeros((V, L, P), bool)
        elif rad.shape[-1] != radiance.shape[-1]:
            raise ValueError(f"{photos.folder}: camera {view.name} has {rad.shape[-1]} channels, "
                             f"camera {photos.names[0]} {radiance.shape[-1]}")
        taps, w, cos_o, seen, reasons = stage.project_texels(mesh, surface, view.camera, mask=view.mask,
                                                             grazing_deg=grazing_deg, occluder=occluder)
        idx = np.flatnonzero(seen)
        radiance[v][:, idx], obs = sample_taps(rad, ok_px, taps[idx], w[idx])  # [L, n, C], [L, n]
        if lit is not None:
            obs &= lit[:, idx]
        mask[v][:, idx] = obs
        weight[v, idx] = cos_o[idx]
        rejected.append(reasons)
        valid_frac.append(float(obs.mean()) if obs.size else 0.0)
        del view, rad, ok_px
        bar.advance(1)
    report = PhotoTexelReport.of(surface, weight, rejected, valid_frac, photos.names, grazing_deg=grazing_deg,
                                 min_views=min_views, shadows=shadows)
    mask[:, :, report.unseen] = False
    radiance = np.where(mask[..., None], radiance, np.float32(0))
    capture = stage.Capture(radiance=jnp.asarray(radiance), mask=jnp.asarray(mask), rig=photos.rig,
                            cameras=tuple(photos.cameras))
    return capture, surface, report

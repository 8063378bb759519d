"""Surface samples projected into a photograph: the pixels each sample reads, and whether the camera sees it."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._camera import Camera
from ._mesh import Mesh
from ._surface import Surface
from ._visibility import Occluder, camera_visibility

# Rejection reasons of ``project_texels``, in the order they are applied (each counts samples still in the running).
PROJECTION_REJECTIONS = ("behind_or_outside_image", "back_facing", "grazing", "outside_mask", "occluded")
# Samples per block of ``project_texels``.
_BLOCK = 1 << 17


class TexelProjection(NamedTuple):
    """What ``project_texels`` found, per sample.

    Fields:
        taps: int64 [P, 4]: the four pixels around the sample's projection (flat
            index ``row * width + column``; -1 outside the image).
        weights: float64 [P, 4]: their bilinear weights (summing to 1).
        cos_o: float64 [P]: cos theta_o, the normal against the direction to the camera.
        seen: bool [P]: the camera sees the sample (in front of it, its four taps in the
            image and the mask, facing it within the grazing limit, not occluded).
        rejected: the count of samples rejected per reason (``PROJECTION_REJECTIONS``,
            applied in that order).
    """

    taps: np.ndarray
    weights: np.ndarray
    cos_o: np.ndarray
    seen: np.ndarray
    rejected: dict


def bilinear_taps(pix: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """The four pixel taps of points in an image, and their bilinear weights.

    Args:
        pix: float [n, 2] pixel coordinates (pixel centres at integer + 0.5, ``Camera``'s convention).
        width: the image's width.
        height: the image's height.

    Returns:
        (taps int64 [n, 4], flat index ``row * width + column``, -1 outside the image; weights [n, 4]).
    """
    x = pix[:, 0] - 0.5
    y = pix[:, 1] - 0.5
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    fx, fy = x - x0, y - y0
    xs = np.stack([x0, x0 + 1, x0, x0 + 1], 1)
    ys = np.stack([y0, y0, y0 + 1, y0 + 1], 1)
    w = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], 1)
    inside = (xs >= 0) & (xs < width) & (ys >= 0) & (ys < height)
    return np.where(inside, ys * width + xs, -1), w


def project_texels(mesh: Mesh, surface: Surface, camera: Camera, *, mask=None, grazing_deg: float = 80.0,
                   occluder: Occluder | None = None) -> TexelProjection:
    """Project surface samples into a camera's image: the pixels each reads and whether the camera sees it.

    Each sample is projected (``Camera.project``; lens distortion is not applied)
    and rejected, in this order, when it is behind the camera or its bilinear
    footprint leaves the image, back-facing (n . wo <= 0), grazing (theta_o >
    ``grazing_deg``), outside ``mask`` (any of its four taps), or occluded (the
    segment to the camera meets the mesh: ``camera_visibility``).

    Args:
        mesh: the occluding mesh.
        surface: the P samples (e.g. ``texel_samples``).
        camera: the camera.
        mask: optional bool [H, W], the image's usable pixels (its size is the image's;
            default: the camera's width and height, every pixel usable).
        grazing_deg: the largest theta_o accepted, in (0, 90].
        occluder: an ``Occluder(mesh, surface)`` reused across cameras (one BVH).

    Returns:
        A :class:`TexelProjection`.
    """
    if not 0 < grazing_deg <= 90:
        raise ValueError(f"project_texels: grazing_deg must be in (0, 90], got {grazing_deg}")
    P = surface.num_samples
    H, W = (camera.height, camera.width) if mask is None else np.shape(mask)
    flat_mask = None if mask is None else np.asarray(mask, bool).reshape(-1)
    cos_graze = float(np.cos(np.deg2rad(grazing_deg)))
    taps, w = np.empty((P, 4), np.int64), np.empty((P, 4), np.float64)
    cos_o, cand = np.empty(P, np.float64), np.empty(P, bool)
    reasons = dict.fromkeys(PROJECTION_REJECTIONS[:-1], 0)
    # In blocks of samples: the projection's float64 temporaries (~200 bytes a sample) stay one block's.
    for s in range(0, P, _BLOCK):
        e = min(s + _BLOCK, P)
        pos = np.asarray(surface.position[s:e], np.float64)
        pix, z = camera.project(pos)
        taps[s:e], w[s:e] = bilinear_taps(np.asarray(pix, np.float64), W, H)
        cos_o[s:e] = np.sum(np.asarray(camera.view_directions(pos), np.float64)
                            * np.asarray(surface.normal[s:e], np.float64), axis=1)
        c = np.ones(e - s, bool)
        for name, keep in (("behind_or_outside_image", (np.asarray(z) > 0) & np.all(taps[s:e] >= 0, axis=1)),
                           ("back_facing", cos_o[s:e] > 0),
                           ("grazing", cos_o[s:e] >= cos_graze)):
            reasons[name] += int(np.sum(c & ~keep))
            c &= keep
        in_mask = c.copy()
        if flat_mask is not None:
            in_mask[c] = np.all(flat_mask[taps[s:e][c]], axis=1)
        reasons["outside_mask"] += int(np.sum(c & ~in_mask))
        cand[s:e] = c & in_mask
    seen = camera_visibility(mesh, surface, [camera], occluder=occluder, candidates=cand)[0]
    reasons["occluded"] = int(np.sum(cand & ~seen))
    return TexelProjection(taps, w, cos_o, seen, reasons)

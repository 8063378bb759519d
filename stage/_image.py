"""Surface samples in image space: one sample per pixel where a primary ray
from the camera hits the mesh (the per-pixel counterpart of ``texel_samples``)."""

from __future__ import annotations

import jax
import numpy as np

from brdf import frame_from_normal_tangent

from ._camera import Camera
from ._mesh import Mesh
from ._surface import Surface
from ._visibility import _padded, primary_hits

# A pixel seen at grazing incidence covers an unbounded area (1 / cos); the
# footprint is capped at this cosine (~89.4 degrees) so areas stay finite.
_GRAZING_COS_MIN = 1e-2


def _face_dpdu(mesh: Mesh) -> np.ndarray:
    V, F = mesh.vertices, mesh.faces
    e1, e2 = V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]
    if mesh.uv is None:
        return e1  # no UV layout: any in-plane direction will do
    UV = mesh.uv
    d1, d2 = UV[F[:, 1]] - UV[F[:, 0]], UV[F[:, 2]] - UV[F[:, 0]]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    safe = np.where(np.abs(det) > 1e-20, det, 1.0)
    return (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) / safe[:, None]


def image_samples(mesh: Mesh, camera: Camera, supersample: int = 1) -> Surface:
    """One surface sample per (sub)pixel whose primary ray hits ``mesh``.

    Position is the ray hit; normal and uv are interpolated from the hit's barycentrics; tangent is dP/du of the
    face (any tangent when the mesh has no UVs; uv is then 0); area (mm^2) is the pixel's footprint on the
    surface, z^2 / (fx fy) * (d . forward) / |d . n| (pinhole; 1 / (fx fy |d . n|) orthographic), with the cosine
    floored at 1e-2.

    Args:
        mesh: the mesh.
        camera: the camera whose pixels are sampled.
        supersample: sub-pixels per pixel along each axis.

    Returns:
        The ``Surface``; ``texel_index`` is the pixel index row * W + column on the (supersampled) image grid
        ``resolution`` = (H, W).

    Raises:
        ValueError: no ray hits the mesh (a camera behind or beside everything).
    """
    hit, face, bary, pos = primary_hits(mesh, camera, supersample)
    h, w = hit.shape
    idx = np.nonzero(hit.ravel())[0]
    if len(idx) == 0:
        c = np.round(np.asarray(camera.center, np.float64), 1).tolist()
        raise ValueError(f"camera at {c} (looking along {np.round(np.asarray(camera.forward), 3).tolist()}) sees no "
                         f"part of mesh '{mesh.name}': it is behind or beside everything")
    f = face.ravel()[idx]
    lam = bary.reshape(-1, 3)[idx]
    p = pos.reshape(-1, 3)[idx]
    tri = mesh.faces[f]
    nrm = np.sum(mesh.normals[tri] * lam[:, :, None], axis=1)
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
    # The interpolated normal may face away from the camera on a silhouette;
    # keep it (the camera-visibility test marks such samples unseen).
    uv = np.zeros((len(idx), 2)) if mesh.uv is None else np.sum(mesh.uv[tri] * lam[:, :, None], axis=1)
    t, b = frame_from_normal_tangent(nrm, _face_dpdu(mesh)[f].copy())
    # Footprint of one (sub)pixel on the surface, using the geometric (face) normal.
    V = mesh.vertices
    ng = np.cross(V[tri[:, 1]] - V[tri[:, 0]], V[tri[:, 2]] - V[tri[:, 0]])
    ng /= np.maximum(np.linalg.norm(ng, axis=1, keepdims=True), 1e-300)
    s = int(supersample)
    fwd = np.asarray(camera.forward, np.float64)
    if camera.orthographic:
        d = np.broadcast_to(fwd, p.shape)
        along = np.ones(len(p))
    else:
        d = p - np.asarray(camera.center, np.float64)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        along = d @ fwd
    cos = np.maximum(np.abs(np.sum(d * ng, axis=1)), _GRAZING_COS_MIN)
    # pixel_area is jitted: its points padded (with the first point) to one of a dozen lengths, so a render in
    # bands of rows does not compile (and keep) a program for every band's hit count.
    n = len(p)
    padded = np.concatenate([p, np.broadcast_to(p[:1], (_padded(n) - n, 3))]) if n else p
    area = np.asarray(camera.pixel_area(padded.astype(np.float32)), np.float64)[:n] / (s * s) * along / cos
    # Cast on the host and device_put: jnp.asarray compiles a program for each sample count (kept by JAX's caches).
    f32 = lambda x: jax.device_put(np.asarray(x, np.float32))  # noqa: E731
    return Surface(position=f32(p), normal=f32(nrm), tangent=f32(t), bitangent=f32(b), uv=f32(uv), area=f32(area),
                   texel_index=jax.device_put(idx.astype(np.int32)), face=jax.device_put(f.astype(np.int32)),
                   resolution=(h, w), barycentric=f32(lam))

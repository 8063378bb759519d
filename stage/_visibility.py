"""Visibility of surface samples from lights and cameras by ray casting.

Computed once per geometry with trimesh's ray intersector (Embree through
embreex where it is installed, trimesh's pure-numpy intersector otherwise);
not differentiated.
"""

from __future__ import annotations

import numpy as np
import trimesh

from ._camera import Camera
from ._mesh import Mesh
from ._rig import Rig
from ._surface import Surface

# Ray origins are pushed off the surface by this fraction of the mesh's
# bounding-box diagonal so a ray does not hit the triangle it starts on.
_OFFSET_FRACTION = 1e-4


def _intersector(mesh: Mesh):
    tm = mesh.trimesh()
    if trimesh.ray.has_embree:
        return trimesh.ray.ray_pyembree.RayMeshIntersector(tm)
    return trimesh.ray.ray_triangle.RayMeshIntersector(tm)


def _origins(mesh: Mesh, surface: Surface) -> np.ndarray:
    diag = np.linalg.norm(mesh.vertices.max(0) - mesh.vertices.min(0))
    p = np.asarray(surface.position, dtype=np.float64)
    n = np.asarray(surface.normal, dtype=np.float64)
    return p + n * (_OFFSET_FRACTION * diag)


def _unoccluded(inter, origins, targets, chunk: int, progress=None) -> np.ndarray:
    """For each (origin, target) pair, True where the segment meets no triangle."""
    out = np.ones(len(origins), dtype=bool)
    for s in range(0, len(origins), chunk):
        o = origins[s:s + chunk]
        d = targets[s:s + chunk] - o
        dist = np.linalg.norm(d, axis=1)
        d = d / np.maximum(dist, 1e-12)[:, None]
        locs, ray_idx, _ = inter.intersects_location(o, d, multiple_hits=False)
        if len(ray_idx):
            hit_dist = np.linalg.norm(locs - o[ray_idx], axis=1)
            blocked = hit_dist < dist[ray_idx]
            out[s + ray_idx[blocked]] = False
        if progress is not None:
            progress(len(o))
    return out


def light_visibility(mesh: Mesh, surface: Surface, rig: Rig, chunk: int = 1 << 20, progress=None) -> np.ndarray:
    """bool [P, L]: sample p sees light l (cast shadows and self-shadowing; a
    light below the sample's tangent plane counts as not visible)."""
    origins = _origins(mesh, surface)
    pos = np.asarray(rig.position, dtype=np.float64)
    n = np.asarray(surface.normal, dtype=np.float64)
    P, L = origins.shape[0], pos.shape[0]
    if rig.near_field:
        to_light = pos[None, :, :] - origins[:, None, :]
    else:
        # A distant light is a point far beyond the mesh along its direction.
        far = 1e3 * (1.0 + np.abs(origins).max())
        dirs = pos / np.linalg.norm(pos, axis=1, keepdims=True)
        to_light = np.broadcast_to(dirs[None] * far, (P, L, 3))
    above = np.einsum("plk,pk->pl", to_light, n) > 0
    pi, li = np.nonzero(above)
    o = origins[pi]
    tgt = o + to_light[pi, li]
    vis = np.zeros((P, L), dtype=bool)
    vis[pi, li] = _unoccluded(_intersector(mesh), o, tgt, chunk, progress)
    return vis


def camera_visibility(mesh: Mesh, surface: Surface, cameras: list[Camera] | tuple[Camera, ...]) -> np.ndarray:
    """bool [V, P]: sample p faces camera v, projects inside its image, and is not occluded."""
    inter = _intersector(mesh)
    origins = _origins(mesh, surface)
    n = np.asarray(surface.normal, dtype=np.float64)
    out = []
    for cam in cameras:
        c = np.asarray(cam.center, dtype=np.float64)
        pix, z = cam.project(surface.position)
        pix, z = np.asarray(pix), np.asarray(z)
        inside = (z > 0) & (pix[:, 0] >= 0) & (pix[:, 0] < cam.width) & (pix[:, 1] >= 0) & (pix[:, 1] < cam.height)
        facing = np.sum((c[None] - origins) * n, axis=1) > 0
        cand = np.nonzero(inside & facing)[0]
        vis = np.zeros(len(origins), dtype=bool)
        vis[cand] = _unoccluded(inter, origins[cand], np.broadcast_to(c, (len(cand), 3)), 1 << 20)
        out.append(vis)
    return np.stack(out)


def primary_hits(mesh: Mesh, camera: Camera, supersample: int = 1):
    """Cast one ray per (sub)pixel from ``camera``: returns hit [H', W'] bool,
    face [H', W'] int (-1 on a miss), barycentrics [H', W', 3] and world
    position [H', W', 3], where H' = supersample * height."""
    s = int(supersample)
    if s < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    h, w = camera.height * s, camera.width * s
    ys, xs = np.meshgrid((np.arange(h) + 0.5) / s, (np.arange(w) + 0.5) / s, indexing="ij")
    origin, d = camera.rays(np.stack([xs, ys], -1).reshape(-1, 2).astype(np.float32))
    d = np.asarray(d, np.float64)
    o = np.broadcast_to(np.asarray(origin, np.float64), d.shape)
    locs, ray_idx, tri_idx = _intersector(mesh).intersects_location(o, d, multiple_hits=False)
    face = np.full(h * w, -1, np.int64)
    pos = np.zeros((h * w, 3))
    face[ray_idx] = tri_idx
    pos[ray_idx] = locs
    bary = np.zeros((h * w, 3))
    if len(ray_idx):
        tri = mesh.vertices[mesh.faces[tri_idx]]
        bary[ray_idx] = trimesh.triangles.points_to_barycentric(tri, locs)
    return face.reshape(h, w) >= 0, face.reshape(h, w), bary.reshape(h, w, 3), pos.reshape(h, w, 3)

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

class PackedMask:
    """A boolean mask [..., N] stored 8 entries per byte along its last axis
    (``np.packbits``, big-endian bit order): the compact form of a visibility
    mask, 1/8 of the bool array. ``unpack(start, stop)`` returns columns
    [start, stop) as bool without unpacking the rest (for light chunks)."""

    def __init__(self, bits: np.ndarray, n: int):
        self.bits = np.ascontiguousarray(bits, dtype=np.uint8)
        self.n = int(n)
        if self.bits.shape[-1] != (self.n + 7) // 8:
            raise ValueError(f"PackedMask: {self.bits.shape[-1]} bytes cannot hold {self.n} entries")

    @classmethod
    def pack(cls, mask) -> "PackedMask":
        """Pack a bool array along its last axis."""
        m = np.asarray(mask, dtype=bool)
        return cls(np.packbits(m, axis=-1), m.shape[-1])

    @property
    def shape(self) -> tuple[int, ...]:
        return self.bits.shape[:-1] + (self.n,)

    @property
    def nbytes(self) -> int:
        return self.bits.nbytes

    def unpack(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """bool [..., stop - start]: columns [start, stop) of the mask."""
        stop = self.n if stop is None else min(int(stop), self.n)
        b0, b1 = start // 8, (stop + 7) // 8
        out = np.unpackbits(self.bits[..., b0:b1], axis=-1, count=None)
        return out[..., start - 8 * b0: stop - 8 * b0].astype(bool)

    def __array__(self, dtype=None, copy=None):
        a = self.unpack()
        return a if dtype is None else a.astype(dtype)

    def save(self, path) -> None:
        """Write to an .npz file atomically (temporary file in the same folder, then os.replace)."""
        import os
        import tempfile
        from pathlib import Path

        path = Path(path)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".npz", dir=path.parent)
        os.close(fd)
        try:
            np.savez_compressed(tmp, bits=self.bits, n=np.int64(self.n))
            os.replace(tmp, path)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise

    @classmethod
    def load(cls, path) -> "PackedMask":
        """Read a mask written by ``save``."""
        with np.load(path) as z:
            return cls(z["bits"], int(z["n"]))


def as_mask(mask, start: int = 0, stop: int | None = None) -> np.ndarray:
    """bool columns [start, stop) of a mask given as bool array or PackedMask."""
    if isinstance(mask, PackedMask):
        return mask.unpack(start, stop)
    return np.asarray(mask, dtype=bool)[..., start:stop]


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


def light_visibility(mesh: Mesh, surface: Surface, rig: Rig, chunk: int = 1 << 20, progress=None,
                     packed: bool = False):
    """bool [P, L]: sample p sees light l (cast shadows and self-shadowing; a
    light below the sample's tangent plane counts as not visible). With
    ``packed``, a ``PackedMask`` (8 lights per byte) instead, never holding the
    bool array. Rays are cast in blocks of about ``chunk`` (peak memory ~ 100
    bytes per ray); ``progress(n)`` is called with the rays done per block."""
    origins = _origins(mesh, surface)
    pos = np.asarray(rig.position, dtype=np.float64)
    n = np.asarray(surface.normal, dtype=np.float64)
    P, L = origins.shape[0], pos.shape[0]
    inter = _intersector(mesh)
    far = 1e3 * (1.0 + np.abs(origins).max())
    dirs = pos / np.linalg.norm(pos, axis=1, keepdims=True)
    # Samples per block so a block's rays (P_b x L x 3 float64) stay near ``chunk`` rays.
    block = max(1, int(chunk) // max(L, 1))
    vis = np.zeros((P, L), dtype=bool) if not packed else None
    bits = np.zeros((P, (L + 7) // 8), np.uint8) if packed else None
    for s in range(0, P, block):
        o_b, n_b = origins[s:s + block], n[s:s + block]
        if rig.near_field:
            to_light = pos[None, :, :] - o_b[:, None, :]
        else:
            # A distant light is a point far beyond the mesh along its direction.
            to_light = np.broadcast_to(dirs[None] * far, (len(o_b), L, 3))
        above = np.einsum("plk,pk->pl", to_light, n_b) > 0
        pi, li = np.nonzero(above)
        o = o_b[pi]
        v_b = np.zeros((len(o_b), L), dtype=bool)
        v_b[pi, li] = _unoccluded(inter, o, o + to_light[pi, li], len(o) + 1, progress)
        if packed:
            bits[s:s + block] = np.packbits(v_b, axis=-1)
        else:
            vis[s:s + block] = v_b
    return PackedMask(bits, L) if packed else vis


def camera_visibility(mesh: Mesh, surface: Surface, cameras: list[Camera] | tuple[Camera, ...] | Camera) -> np.ndarray:
    """bool [V, P]: sample p faces camera v, projects inside its image, and is not occluded."""
    inter = _intersector(mesh)
    origins = _origins(mesh, surface)
    n = np.asarray(surface.normal, dtype=np.float64)
    out = []
    cameras = (cameras,) if isinstance(cameras, Camera) else tuple(cameras)
    for cam in cameras:
        pix, z = cam.project(surface.position)
        pix, z = np.asarray(pix), np.asarray(z)
        inside = (z > 0) & (pix[:, 0] >= 0) & (pix[:, 0] < cam.width) & (pix[:, 1] >= 0) & (pix[:, 1] < cam.height)
        if cam.orthographic:
            # Rays leave toward the image plane (camera z = 0) along -forward.
            back = -np.asarray(cam.forward, np.float64)
            targets = origins + back[None] * (z[:, None] + 1.0)
        else:
            targets = np.broadcast_to(np.asarray(cam.center, dtype=np.float64), origins.shape)
        facing = np.sum((targets - origins) * n, axis=1) > 0
        cand = np.nonzero(inside & facing)[0]
        vis = np.zeros(len(origins), dtype=bool)
        vis[cand] = _unoccluded(inter, origins[cand], targets[cand], 1 << 20)
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
    origin, d = camera.rays(np.stack([xs, ys], -1).reshape(-1, 2).astype(np.float64))
    d = np.asarray(d, np.float64)
    o = np.broadcast_to(np.asarray(origin, np.float64), d.shape)
    if camera.orthographic:
        # The image plane may cut the mesh: start the rays well behind it.
        back = 2.0 * (np.abs(mesh.vertices).max() + np.abs(o).max())
        o = o - d * back
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

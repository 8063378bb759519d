"""Visibility of surface samples from lights and cameras by ray casting.

Computed once per geometry with trimesh's ray intersector (Embree through
embreex where it is installed, trimesh's pure-numpy intersector otherwise);
not differentiated. ``Occluder`` is the one ray caster: ``light_visibility``,
``camera_visibility`` and ``primary_hits`` use it, and so can renderers that
need occlusion queries along arbitrary directions (``Occluder.visible``).

Ray origins follow production renderers: off the triangle along its geometric
normal by a robust, magnitude-scaled epsilon (Waechter & Binder 2019), and for
shadow rays from the smooth surface the interpolated normals describe
(Hanika 2021), so smooth-shaded coarse triangles have no faceted terminator.
"""

from __future__ import annotations

import numpy as np
import trimesh

from ._atomic import atomic_write_bytes
from ._camera import Camera
from ._mesh import Mesh
from ._progress import Phase
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
    def pack(cls, mask) -> PackedMask:
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
        """Write to an .npz file atomically (``stage._atomic``)."""
        atomic_write_bytes(path, lambda fh: np.savez_compressed(fh, bits=self.bits, n=np.int64(self.n)))

    @classmethod
    def load(cls, path) -> PackedMask:
        """Read a mask written by ``save``."""
        with np.load(path) as z:
            return cls(z["bits"], int(z["n"]))


def as_mask(mask, start: int = 0, stop: int | None = None) -> np.ndarray:
    """bool columns [start, stop) of a mask given as bool array or PackedMask."""
    if isinstance(mask, PackedMask):
        return mask.unpack(start, stop)
    return np.asarray(mask, dtype=bool)[..., start:stop]


# Robust ray-origin offset (Waechter & Binder 2019, "A Fast and Robust Method
# for Avoiding Self-Intersection", Ray Tracing Gems ch. 6): the origin moves
# along the geometric normal by _OFFSET_ULPS float32 ulps of the largest
# coordinate of the sample's triangle (their int_scale = 256: Embree intersects
# in float32, so its error in the plane distance scales with the coordinates),
# with _OFFSET_FLOOR_MM (their float_scale = 2^-16) near the origin.
_OFFSET_ULPS = 256.0
_OFFSET_FLOOR_MM = 2.0 ** -16


def face_normals(mesh: Mesh, face) -> np.ndarray:
    """float64 [P, 3]: the unit geometric (flat) normal of triangle ``face[p]``,
    by its winding (e1 x e2)."""
    V, F = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces)[np.asarray(face)]
    ng = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    return ng / np.maximum(np.linalg.norm(ng, axis=1, keepdims=True), 1e-300)


def terminator_point(mesh: Mesh, face, barycentric, position) -> np.ndarray:
    """float64 [P, 3]: the shadow-ray origin on the smooth surface that the
    interpolated normals describe (Hanika 2021, "Hacking the Shadow
    Terminator", Ray Tracing Gems II ch. 4, eq. 4.2-4.3).

    The point p = sum_i b_i v_i of a flat triangle is projected onto each
    vertex's tangent plane (v_i, n_i), only where it lies below it (convex
    parts: the flat triangle lies inside the smooth surface), and the
    projections are blended with the same barycentrics:
    p' = p - sum_i b_i min(0, (p - v_i) . n_i) n_i. p' = p on flat and concave
    parts. Shading at p with a smooth normal but casting shadows from the flat
    triangle darkens the light side of the terminator in facets (each coarse
    triangle shadows itself where its flat plane turns away from the light);
    from p' a ray toward a light the smooth surface sees escapes."""
    V, N = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.normals, np.float64)
    F = np.asarray(mesh.faces)[np.asarray(face)]
    b = np.asarray(barycentric, np.float64)
    p = np.asarray(position, np.float64)
    lift = np.zeros_like(p)
    for i in range(3):
        n_i = N[F[:, i]]
        h = np.minimum(np.sum((p - V[F[:, i]]) * n_i, axis=1), 0.0)
        lift -= (b[:, i] * h)[:, None] * n_i
    return p + lift


def offset_origin(mesh: Mesh, face, point, normal) -> np.ndarray:
    """float64 [P, 3]: ``point`` moved along the unit ``normal`` by the robust
    epsilon of ``_OFFSET_ULPS`` float32 ulps of the largest coordinate of the
    point and of triangle ``face[p]`` (Waechter & Binder 2019), at least
    ``_OFFSET_FLOOR_MM``: enough that the float32 ray caster never finds the
    sample's own triangle in front of a ray leaving on the normal's side, and
    far below any feature of the mesh (~2e-3 mm at 100 mm)."""
    V, F = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces)[np.asarray(face)]
    mag = np.maximum(np.abs(V[F]).max(axis=(1, 2)), np.abs(point).max(axis=1))
    eps = np.maximum(_OFFSET_ULPS * float(np.finfo(np.float32).eps) * mag, _OFFSET_FLOOR_MM)
    return np.asarray(point, np.float64) + eps[:, None] * normal


# Samples per block of ``Occluder``'s construction.
_OCCLUDER_BLOCK = 1 << 17


class Occluder:
    """Occlusion queries against ``mesh`` from the samples of ``surface``.

    Two ray origins per sample, both moved off the triangle along its
    GEOMETRIC normal (oriented to the shading normal's side) by a robust
    epsilon (``offset_origin``, Waechter & Binder 2019), so a ray leaving on
    that side never hits the triangle it starts on:

    * ``origin`` (shadow rays, ``visible`` and ``light_visibility``): the
      sample's shadow-terminator point on the smooth surface of the
      interpolated normals (``terminator_point``, Hanika 2021), so coarse
      triangles do not shadow themselves on the light side of the terminator
      (shading uses the interpolated normal; the flat facet would cut its
      cosine lobe off in straight-edged steps). Where the lift would cross
      other geometry (a thin part: an ear rim, an eyelid) the sample keeps
      its point on the triangle, so the lift never lets light through a
      surface.
    * ``surface_origin`` (camera rays, ``camera_visibility``): the point on
      the triangle itself: a camera sees the mesh's flat triangles, as its
      primary rays (``primary_hits``) do.

    With ``terminator=False`` shadow rays leave from ``surface_origin`` too:
    the flat facets' own shadows, as a renderer without a terminator fix
    (Mitsuba 3, pbrt-v4) casts them, for like-for-like comparisons.

    A direction below the sample's shading tangent plane (``dot(d, n) <= 0``,
    n the interpolated normal ``surface.normal``) counts as blocked.
    ``surface.face`` must index ``mesh.faces`` (``texel_samples`` and
    ``image_samples`` of this mesh); a ``surface.barycentric`` of None is
    recomputed from the positions.

    Attributes (mm): ``origin`` [P, 3] and ``surface_origin`` [P, 3] (float64), ``normal`` [P, 3] (shading,
    interpolated: ``surface.normal`` as it is, not copied; every use promotes it to float64, exactly);
    ``geometric_normal`` [P, 3] (float64, computed when read: construction needs it a block at a time, and
    nothing holds it, ~24 bytes a sample); ``terminator`` (bool, as built); and ``intersector`` (trimesh's
    ``RayMeshIntersector``: Embree through embreex where installed, else trimesh's numpy one).

    ``bvh``: an Occluder of the same mesh whose ray caster (BVH) is reused, so the samples of a large
    surface can be taken a block at a time (an ``Occluder`` per block, one BVH) with the same answers.
    """

    def __init__(self, mesh: Mesh, surface: Surface | None = None, terminator: bool = True, *,
                 bvh: Occluder | None = None):
        self.terminator = bool(terminator)
        if bvh is not None:
            if bvh._mesh is not mesh and np.shape(bvh._mesh.faces) != np.shape(mesh.faces):
                raise ValueError(f"Occluder: bvh was built for a mesh of {len(bvh._mesh.faces)} faces, this mesh "
                                 f"has {len(mesh.faces)}")
            self.intersector = bvh.intersector
        elif trimesh.ray.has_embree:
            self.intersector = trimesh.ray.ray_pyembree.RayMeshIntersector(mesh.trimesh())
        else:  # pragma: no cover - the pure-numpy intersector is slow but correct
            self.intersector = trimesh.ray.ray_triangle.RayMeshIntersector(mesh.trimesh())
        self._mesh, self._face = mesh, None
        if surface is None:
            self.normal = self.origin = self.surface_origin = np.zeros((0, 3))
            return
        self.normal = np.asarray(surface.normal)
        face = np.asarray(surface.face)
        if face.shape != (self.normal.shape[0],) or (len(face) and (face.min() < 0 or face.max() >= len(mesh.faces))):
            raise ValueError(f"Occluder: surface.face must index the mesh's {len(mesh.faces)} faces "
                             "(a surface sampled from this mesh)")
        P = len(face)
        self._face = face
        self.surface_origin = np.empty((P, 3))
        self.origin = self.surface_origin if not terminator else np.empty((P, 3))
        # In blocks of samples: the per-triangle gathers ([n, 3, 3] float64) stay one block's.
        for s in range(0, P, _OCCLUDER_BLOCK):
            r = slice(s, min(s + _OCCLUDER_BLOCK, P))
            self._build(mesh, surface, face[r], r, terminator)

    @property
    def geometric_normal(self) -> np.ndarray:
        """float64 [P, 3]: each sample's unit geometric normal (``face_normals``), on its shading normal's side
        (pbrt-v4's FaceForward of n_g to n_s): the direction its origins were moved along."""
        if self._face is None:
            return np.zeros((0, 3))
        out = np.empty((len(self._face), 3))
        for s in range(0, len(self._face), _OCCLUDER_BLOCK):
            r = slice(s, min(s + _OCCLUDER_BLOCK, len(self._face)))
            out[r] = self._facing_normal(self._mesh, self._face[r], r)
        return out

    def _facing_normal(self, mesh: Mesh, face: np.ndarray, r: slice) -> np.ndarray:
        """float64 [n, 3]: the geometric normals of samples ``r`` (their triangles ``face``), turned to the side
        of their shading normals."""
        ng = face_normals(mesh, face)
        return np.where(np.sum(ng * self.normal[r], axis=1, keepdims=True) < 0, -ng, ng)

    def _build(self, mesh: Mesh, surface: Surface, face: np.ndarray, r: slice, terminator: bool) -> None:
        """The origins and geometric normals of samples ``r`` (their triangles ``face``)."""
        pos = np.asarray(surface.position[r], np.float64)
        if surface.barycentric is None:
            tri = np.asarray(mesh.vertices, np.float64)[np.asarray(mesh.faces)[face]]
            bary = trimesh.triangles.points_to_barycentric(tri, pos) if len(face) else np.zeros((0, 3))
        else:
            bary = np.asarray(surface.barycentric[r], np.float64)
        ng = self._facing_normal(mesh, face, r)
        self.surface_origin[r] = offset_origin(mesh, face, pos, ng)
        if not terminator:
            return
        lifted = offset_origin(mesh, face, terminator_point(mesh, face, bary, pos), ng)
        moved = np.flatnonzero(np.any(lifted != self.surface_origin[r], axis=1))
        if len(moved):
            # The lift (<= a few % of the triangle's size) must not cross another surface.
            crossed = ~self.segments_clear(self.surface_origin[r][moved], lifted[moved])
            lifted[moved[crossed]] = self.surface_origin[r][moved[crossed]]
        self.origin[r] = lifted

    def visible(self, idx, dirs, active=None, distance=None) -> np.ndarray:
        """bool [n, k]: sample ``idx[i]`` sees along ``dirs[i, j]``.

        Args:
            idx: [n] sample indices into the surface.
            dirs: [n, k, 3] unit world directions.
            active: optional bool [n, k]; inactive pairs are False, and cast no ray.
            distance: optional [n, k] mm: a hit counts only nearer than this
                (a segment to a point light); None for rays to infinity.
        """
        idx = np.asarray(idx)
        dirs = np.asarray(dirs, np.float64)
        n, k = dirs.shape[:2]
        cast = np.einsum("nkc,nc->nk", dirs, self.normal[idx]) > 0
        if active is not None:
            cast &= np.asarray(active, bool)
        out = np.zeros((n, k), bool)
        ii, jj = np.nonzero(cast)
        if len(ii):
            o = self.origin[idx[ii]]
            d = dirs[ii, jj]
            if distance is None:
                out[ii, jj] = ~self.intersector.intersects_any(o, d)
            else:
                out[ii, jj] = self.segments_clear(o, o + d * np.asarray(distance, np.float64)[ii, jj, None])
        return out

    def segments_clear(self, origins, targets, chunk: int = 1 << 18) -> np.ndarray:
        """bool [N]: the segment from ``origins[i]`` to ``targets[i]`` (both [N, 3],
        world, mm) meets no triangle. Rays are cast in blocks of ``chunk``."""
        origins = np.asarray(origins, np.float64)
        targets = np.asarray(targets, np.float64)
        out = np.ones(len(origins), dtype=bool)
        for s in range(0, len(origins), max(1, int(chunk))):
            o = origins[s:s + chunk]
            d = targets[s:s + chunk] - o
            dist = np.linalg.norm(d, axis=1)
            d = d / np.maximum(dist, 1e-12)[:, None]
            locs, ray_idx, _ = self.intersector.intersects_location(o, d, multiple_hits=False)
            if len(ray_idx):
                hit_dist = np.linalg.norm(locs - o[ray_idx], axis=1)
                blocked = hit_dist < dist[ray_idx]
                out[s + ray_idx[blocked]] = False
        return out


def light_visibility(mesh: Mesh, surface: Surface, rig: Rig, chunk: int = 1 << 20, progress=None,
                     packed: bool = False, terminator: bool = True, occluder: Occluder | None = None):
    """bool [P, L]: sample p sees light l (cast shadows and self-shadowing; a
    light below the sample's tangent plane counts as not visible). With
    ``packed``, a ``PackedMask`` (8 lights per byte) instead, never holding the
    bool array. Rays are cast in blocks of about ``chunk`` (peak memory ~ 100
    bytes per ray); ``progress(phase, done, total)`` (``stage.Progress``) is
    told the (sample, light) pairs done, phase "light visibility", after each
    block. Every ray is cast by :class:`Occluder` (``terminator``: its
    shadow-terminator origins, the default; False: from the flat facets). ``occluder``: one already built for
    ``mesh`` and ``surface`` (with terminator origins unless ``terminator`` is False), reused instead of building
    another (its BVH and per-sample origins are ~100 bytes a sample)."""
    occ = Occluder(mesh, surface, terminator) if occluder is None else occluder
    if occ.terminator != bool(terminator):
        raise ValueError(f"light_visibility: terminator={terminator} but the occluder was built with "
                         f"terminator={occ.terminator}")
    if occ.origin.shape[0] != surface.num_samples:
        raise ValueError(f"light_visibility: the occluder holds {occ.origin.shape[0]} samples, the surface "
                         f"{surface.num_samples}: build it for this surface")
    pos = np.asarray(rig.position, dtype=np.float64)
    P, L = occ.origin.shape[0], pos.shape[0]
    dirs = pos / np.linalg.norm(pos, axis=1, keepdims=True)
    # Samples per block so a block's rays (P_b x L x 3 float64) stay near ``chunk`` rays.
    block = max(1, int(chunk) // max(L, 1))
    bar = Phase(progress, "light visibility", P * L)
    vis = np.zeros((P, L), dtype=bool) if not packed else None
    bits = np.zeros((P, (L + 7) // 8), np.uint8) if packed else None
    for s in range(0, P, block):
        idx = np.arange(s, min(s + block, P))
        if rig.near_field:
            # A point light: the segment from the sample to the light.
            to_light = pos[None, :, :] - occ.origin[idx, None, :]
            dist = np.linalg.norm(to_light, axis=-1)
            v_b = occ.visible(idx, to_light / np.maximum(dist, 1e-12)[..., None], distance=dist)
        else:
            # A distant light: a ray to infinity along its direction.
            v_b = occ.visible(idx, np.broadcast_to(dirs[None], (len(idx), L, 3)))
        if packed:
            bits[s:s + block] = np.packbits(v_b, axis=-1)
        else:
            vis[s:s + block] = v_b
        bar.advance(len(idx) * L)
    return PackedMask(bits, L) if packed else vis


def _padded(n: int) -> int:
    """The length a batch of ``n`` samples is padded to for a JAX call: the next power of two, at least 2^10, so
    a stream of batches of any lengths compiles (and JAX keeps) programs for a dozen lengths, not for each one."""
    return 1 << max(10, (int(n) - 1).bit_length())


def camera_visibility(mesh: Mesh, surface: Surface, cameras: list[Camera] | tuple[Camera, ...] | Camera, *,
                      occluder: Occluder | None = None, candidates=None, chunk: int | None = None) -> np.ndarray:
    """bool [V, P]: sample p faces camera v, projects inside its image, and is not occluded.

    Args:
        mesh: the occluding mesh.
        surface: the P samples.
        cameras: one ``Camera`` or a sequence of V.
        occluder: an ``Occluder(mesh, surface)`` built once and reused across
            calls (building one costs a BVH).
        candidates: bool [P]: only these samples are tested (ray cast), the others are False.
        chunk: test this many samples at a time, each chunk with its own occluder
            (not with ``occluder``): the answer is the same (each sample is its own
            ray), while the pass's temporaries (the occluder's float64 copies, the
            projections and rays: a few hundred bytes a sample) stay one chunk's.
            None: all at once.

    Returns:
        bool [V, P].
    """
    P = surface.num_samples
    if chunk is not None and occluder is None and P > int(chunk):
        from ._host import host_fields, host_subset

        if int(chunk) < 1:
            raise ValueError(f"camera_visibility: chunk must be >= 1, got {chunk}")
        cams = (cameras,) if isinstance(cameras, Camera) else tuple(cameras)
        fields = host_fields(surface)
        out = np.zeros((len(cams), P), bool)
        for s in range(0, P, int(chunk)):
            part = slice(s, min(s + int(chunk), P))
            out[:, part] = camera_visibility(mesh, host_subset(fields, surface.resolution, part), cams,
                                             candidates=None if candidates is None else np.asarray(candidates)[part])
        return out
    occ = Occluder(mesh, surface) if occluder is None else occluder
    if occ.origin.shape != (P, 3):
        raise ValueError(f"camera_visibility: occluder was built for {occ.origin.shape[0]} samples, surface has {P}")
    if candidates is not None:
        candidates = np.asarray(candidates)
        if candidates.shape != (P,) or candidates.dtype != bool:
            raise ValueError(f"camera_visibility: candidates must be bool [{P}], got {candidates.dtype} "
                             f"{candidates.shape}")
    # Only the candidates are projected and cast, a block at a time (their float64 copies and the rays are what
    # a call holds).
    pick = np.arange(P) if candidates is None else np.flatnonzero(candidates)
    cameras = (cameras,) if isinstance(cameras, Camera) else tuple(cameras)
    out = np.zeros((len(cameras), P), bool)
    positions = np.asarray(surface.position)
    for s in range(0, len(pick), _OCCLUDER_BLOCK):
        idx = pick[s:s + _OCCLUDER_BLOCK]
        origins, n = occ.surface_origin[idx], occ.normal[idx]
        # Projected in a few padded sizes: JAX compiles (and keeps) its eager operations for every new length, and
        # the candidates of each call and block would be a new one.
        position = positions[np.pad(idx, (0, _padded(len(idx)) - len(idx)), mode="edge")]  # idx is never empty
        for v, cam in enumerate(cameras):
            pix, z = cam.project(position)
            pix, z = np.asarray(pix)[:len(idx)], np.asarray(z)[:len(idx)]
            inside = (z > 0) & (pix[:, 0] >= 0) & (pix[:, 0] < cam.width) & (pix[:, 1] >= 0) & (pix[:, 1] < cam.height)
            if cam.orthographic:
                # Rays leave toward the image plane (camera z = 0) along -forward.
                back = -np.asarray(cam.forward, np.float64)
                targets = origins + back[None] * (z[:, None] + 1.0)
            else:
                targets = np.broadcast_to(np.asarray(cam.center, dtype=np.float64), origins.shape)
            cand = np.nonzero(inside & (np.sum((targets - origins) * n, axis=1) > 0))[0]
            out[v, idx[cand]] = occ.segments_clear(origins[cand], targets[cand])
    return out


def primary_hits(mesh: Mesh, camera: Camera, supersample: int = 1, occluder: Occluder | None = None):
    """Cast one ray per (sub)pixel from ``camera``: returns hit [H', W'] bool,
    face [H', W'] int (-1 on a miss), barycentrics [H', W', 3] and world
    position [H', W', 3], where H' = supersample * height. ``occluder``: an
    ``Occluder(mesh)`` reused (its BVH) when called for many cameras or bands of
    one (``Camera.crop``)."""
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
    occ = Occluder(mesh) if occluder is None else occluder
    locs, ray_idx, tri_idx = occ.intersector.intersects_location(o, d, multiple_hits=False)
    face = np.full(h * w, -1, np.int64)
    pos = np.zeros((h * w, 3))
    face[ray_idx] = tri_idx
    pos[ray_idx] = locs
    bary = np.zeros((h * w, 3))
    if len(ray_idx):
        tri = mesh.vertices[mesh.faces[tri_idx]]
        bary[ray_idx] = trimesh.triangles.points_to_barycentric(tri, locs)
    return face.reshape(h, w) >= 0, face.reshape(h, w), bary.reshape(h, w, 3), pos.reshape(h, w, 3)

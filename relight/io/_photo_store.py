"""Photographs to a texel capture store, streamed: a delivery of any size resampled onto a mesh's texel grid
in bounded memory, written as the chunked store (``.zarr``) that ``relight fit`` streams from.

:func:`relight.io.photos_to_texels` builds the whole texel capture [V, L, P, C] in memory and reads each
camera's whole stack of photographs; one Light Stage X camera at 2048^2 is 346 x 4.2 M pixels x RGB, 17 GiB as
float32. Here a camera's photographs are read a light chunk at a time and every chunk of texels is written as
soon as it is complete, so memory is set by the chunk sizes (the light chunk's images and the texel grid's
compact per-texel geometry, found a block of texels at a time), not by the number of lights.
"""

from __future__ import annotations

import hashlib
import os
from typing import NamedTuple

import numpy as np

import stage

from ._photo_texels import PhotoTexelReport, check_texel_arguments, sample_taps
from ._photos import PhotoCapture
from ._store import LIGHT_CHUNK, CaptureStoreWriter, default_chunks

# Texels per write: the grid is written in runs of this many texels, so no [Lc, H * W, C] array is built.
_WRITE_TEXELS = 1 << 16
# Shadow rays per block of the light visibility (~100 bytes a ray).
_RAY_CHUNK = 1 << 18
# Texels sampled per call of sample_taps: their four taps (int32) and sample_taps' temporaries stay a block's.
_TAP_TEXELS = 1 << 16
# Photograph values (pixels x channels) read at once, as float32: 16 MiB, a light or two of a 1024^2 camera.
_READ_VALUES = 1 << 22


class _CameraTexels(NamedTuple):
    """One camera's view of the texel grid, compact (28 bytes a texel it sees): the texels it sees ``idx`` int32
    [n] (in grid order), their grid cells ``cells`` int32 [n], the first of their bilinear taps ``tap`` int32 [n]
    (the four are ``tap + (0, 1, width, width + 1)``: a seen texel's four taps all lie in the image) and their
    weights ``weights`` float32 [n, 4], the image's ``width`` and the projection's rejection counts."""

    idx: np.ndarray
    cells: np.ndarray
    tap: np.ndarray
    weights: np.ndarray
    width: int
    rejected: dict

    def taps(self, s: int = 0, e: int | None = None) -> np.ndarray:
        """int32 [e - s, 4]: the four bilinear taps (flat pixel indices) of seen texels s:e."""
        return self.tap[s:e, None] + np.array([0, 1, self.width, self.width + 1], np.int32)


# Texels per block of the geometry (projections, occlusion, cast shadows): the block's float64 origins,
# projections and rays (a few hundred bytes a texel) are what it holds beyond the compact results. A multiple of
# stage's own projection block (2^17), so the projections are cut where the whole grid's are.
_GEOMETRY_BLOCK = 1 << 17


# The texel surface's fields the geometry reads (44 of its 80 bytes a texel): the frame, uv and area are not.
_GEOMETRY_FIELDS = ("position", "normal", "face", "barycentric", "texel_index")


def _geometry(mesh, fields: dict, resolution, photos: PhotoCapture, grazing_deg: float, shadows: bool, progress):
    """Every camera's :class:`_CameraTexels`, their cos theta_o ``weight`` float32 [V, P] (0 where unseen) and,
    with ``shadows``, the cast shadows of the texels some camera sees, ``(stage.PackedMask [n, L], their texel
    indices int64 [n], increasing)`` (the others' are never read: no ray is cast for them), of the texel surface
    whose ``_GEOMETRY_FIELDS`` are ``fields`` (NumPy), computed ``_GEOMETRY_BLOCK`` texels at a time: an
    ``Occluder`` per block on one BVH, so only the compact results are whole-grid (the answers are each texel's
    own rays: the same as for the whole grid at once)."""
    P, V, L = len(fields["position"]), photos.n_views, photos.n_lights
    grid = fields["texel_index"]
    bvh = stage.Occluder(mesh)
    masks = [photos.read_mask(v) for v in range(V)]
    width = [int(np.shape(m)[1]) for m in masks]
    parts = [[] for _ in range(V)]
    rejected = [dict.fromkeys(stage.PROJECTION_REJECTIONS, 0) for _ in range(V)]
    weight = np.zeros((V, P), np.float32)
    lit_parts = []  # (texel indices, packed bits) of each block's texels that some camera sees
    bar = stage.Phase(progress if shadows else None, "light visibility", P * L)  # counts the grid's pairs
    report = None if progress is None else (lambda phase, done, total: progress(phase, bar.done + done, P * L))
    for s in range(0, P, _GEOMETRY_BLOCK):
        e = min(s + _GEOMETRY_BLOCK, P)
        block = _block_surface(fields, resolution, s, e)
        # The cameras' rays leave from the triangles (surface_origin): no terminator origins, whose lift is
        # checked by casting a ray, for texels no light ray leaves from.
        occ = stage.Occluder(mesh, block, terminator=False, bvh=bvh)
        any_seen = np.zeros(e - s, bool)
        for v in range(V):
            pr = stage.project_texels(mesh, block, photos.cameras[v], mask=masks[v], grazing_deg=grazing_deg,
                                      occluder=occ)
            seen = np.flatnonzero(pr.seen)
            tap = pr.taps[seen, 0].astype(np.int32)
            if not np.array_equal(pr.taps[seen], tap[:, None] + np.array([0, 1, width[v], width[v] + 1])):
                raise AssertionError("photos_to_texel_store: a seen texel's bilinear taps are not a 2 x 2 square")
            parts[v].append(((seen + s).astype(np.int32), tap, pr.weights[seen].astype(np.float32)))
            weight[v, seen + s] = pr.cos_o[seen]
            any_seen |= pr.seen
            rejected[v] = {k: rejected[v][k] + int(n) for k, n in pr.rejected.items()}
            del pr
        del block, occ
        sel = s + np.flatnonzero(any_seen)
        if shadows and len(sel):
            sub = _block_surface(fields, resolution, sel)
            lit_parts.append((sel, stage.light_visibility(mesh, sub, photos.rig, chunk=_RAY_CHUNK, packed=True,
                                                          progress=report, occluder=stage.Occluder(mesh, sub, bvh=bvh)
                                                          ).bits))
            del sub
        bar.advance((e - s) * L)
        stage.release_freed_memory()  # the block's origins, projections and rays
    views = []
    for v in range(V):
        idx, tap, w = (np.concatenate(x) for x in zip(*parts[v], strict=True))
        parts[v] = None
        order = np.argsort(grid[idx], kind="stable")  # _write_grid wants the texels in grid order
        views.append(_CameraTexels(idx[order], grid[idx[order]].astype(np.int32), tap[order], w[order], width[v],
                                   rejected[v]))
    if not shadows:
        return views, weight, None
    rows = np.concatenate([r for r, _ in lit_parts]) if lit_parts else np.zeros(0, np.int64)
    bits = np.concatenate([b for _, b in lit_parts]) if lit_parts else np.zeros((0, (L + 7) // 8), np.uint8)
    return views, weight, (stage.PackedMask(bits, L), rows)


def _block_surface(fields: dict, resolution, s, e: int | None = None) -> stage.Surface:
    """Texels s:e (or the texels ``s``, an index array) of the surface held as ``fields`` (``_GEOMETRY_FIELDS``),
    as a ``stage.Surface`` whose tangent, bitangent, uv and area, which the geometry does not read, are zero."""
    import jax

    at = slice(s, e) if e is not None else s
    put = {k: jax.device_put(fields[k][at]) for k in _GEOMETRY_FIELDS}
    zero = np.zeros((len(put["position"]), 3), fields["position"].dtype)
    return stage.Surface(**put, tangent=jax.device_put(zero), bitangent=jax.device_put(zero),
                         uv=jax.device_put(zero[:, :2]), area=jax.device_put(zero[:, 0]), resolution=tuple(resolution))


def photos_to_texel_store(photos: PhotoCapture, mesh: stage.Mesh, resolution: int | tuple[int, int],
                          path: str | os.PathLike, *, surface_info: dict, grazing_deg: float = 80.0,
                          min_views: int = 1, shadows: bool = True, light_chunk: int = LIGHT_CHUNK,
                          resume: bool = False, progress=None) -> tuple[stage.Surface, PhotoTexelReport]:
    """Resample a photo capture onto the texel grid of ``mesh`` and write it as a texel capture store, streaming:
    the same observations as :func:`relight.io.photos_to_texels` (bilinear taps, the same rejections, validity
    and cast shadows; tested equal), never holding more than one light chunk of one camera's photographs.

    The store covers the whole texel grid [V, L, H * W, C] (float32; texels outside the UV atlas or seen by
    fewer than ``min_views`` cameras hold no valid observation), with ``metadata`` ``{"space": "texel",
    "surface": surface_info + resolution, "photos": the report's summary}``, so ``relight fit STORE`` rebuilds
    the surface and fits it block by block (``relight.io.open_texel_capture``). It is built in ``.NAME.partial``
    beside ``path`` and renamed into place when complete (``CaptureStoreWriter`` with ``partial``): a killed
    conversion leaves no store, and a conversion run again with ``resume`` keeps every light chunk of every camera
    that the killed one finished (checkpointed after each; the photographs, the mesh and the settings must be the
    same: the files' sizes and modification times, capture.json, the rig and the cameras are compared) and reads
    only the rest. The store is the same, chunk for chunk, as that of one uninterrupted run.

    Args:
        photos: an opened photo capture (``relight.io.read_photo_capture``).
        mesh: the mesh with UVs whose atlas is the texel grid, in the stage frame (mm).
        resolution: the texel grid, N or (H, W) (``stage.texel_samples``).
        path: the store to write (a ``.zarr`` folder; an existing store is replaced).
        surface_info: how to load ``mesh`` again (``relight.io.mesh_spec``), recorded for the fit.
        grazing_deg, min_views, shadows: as :func:`relight.io.photos_to_texels`.
        light_chunk: the store's light chunk, the lights resampled before each write (peak memory: while the
            geometry is found, ``_GEOMETRY_BLOCK`` texels at a time, the surface fields it reads, 44 bytes a
            texel; then, no surface until the end, where it is rasterised again (~80 bytes a texel, returned), and
            the geometry's compact results: each camera's taps, 28 bytes a texel it sees, the cos
            theta_o weights, 4 bytes a texel a camera, and the cast shadows, 1 bit a (texel, light), plus
            light_chunk x the texels a camera sees x channels x 4 bytes; the photographs are read
            ``_READ_VALUES`` values, 16 MiB as float32, at a time).
        resume: keep what a killed conversion of the same photographs into ``path`` with the same settings
            finished (else an earlier partial store is cleared).
        progress: ``stage.Progress``: "light visibility" (with ``shadows``), then "photos to texels" counting
            (camera, light) photographs.

    Returns:
        ``(surface, report)``: the texels' ``stage.Surface`` (every texel of the grid inside the atlas) and the
        :class:`relight.io.PhotoTexelReport`.

    Raises:
        ValueError naming the argument or the camera (channel counts that differ between cameras);
        ``relight.io.ImageFormatError`` naming a photograph that cannot be read; with ``resume``,
        ``relight.io.PartialStoreMismatch`` when the partial store there is of other photographs or settings.
    """
    check_texel_arguments("photos_to_texel_store", grazing_deg, min_views)
    if isinstance(light_chunk, bool) or int(light_chunk) != light_chunk or light_chunk < 1:
        raise ValueError(f"photos_to_texel_store: light_chunk must be an integer >= 1, got {light_chunk!r}")
    surface = stage.texel_samples(mesh, resolution)
    H, W = surface.resolution
    N, V, L = H * W, photos.n_views, photos.n_lights
    # What the geometry reads (views of the surface's buffers); the rest of the surface (~36 bytes a texel) is not
    # needed until the end, where it is rasterised again (the same surface: texel_samples is deterministic).
    fields = {k: np.asarray(getattr(surface, k)) for k in _GEOMETRY_FIELDS}
    del surface
    stage.release_freed_memory()  # the rasterisation's temporaries
    C = photos.read_view(0, lights=[0]).radiance.shape[-1]
    lc = min(int(light_chunk), L)
    _, _, pc, _ = default_chunks((V, lc, N, C), np.float32)
    cameras = [stage.camera_to_dict(c, n) for c, n in zip(photos.cameras, photos.names, strict=True)]
    meta = {"space": "texel", "surface": {**dict(surface_info), "resolution": [int(H), int(W)]},
            "source": {"photo_capture": str(photos.folder)}}
    valid_frac = []
    of = {"photos": photo_fingerprint(photos), "mesh": _mesh_digest(mesh), "grazing_deg": float(grazing_deg),
          "min_views": int(min_views), "shadows": bool(shadows)}
    with CaptureStoreWriter(path, (V, L, N, C), np.float32, rig=photos.rig, cameras=cameras, metadata=meta,
                            chunks=(1, lc, pc, C), sample_shape=(H, W), partial=of, resume=resume) as writer:
        finished = {(int(e["view"]), int(e["light"])): int(e["valid"]) for e in writer.checkpoints
                    if writer.written(int(e["view"]), slice(int(e["light"]), min(int(e["light"]) + lc, L)))}
        # The geometry of every camera first, a block of texels at a time, so no pixel is read while it is held;
        # lit: the cast shadows, 1 bit per (texel some camera sees, light), unpacked a light chunk at a time.
        views, weight, lit = _geometry(mesh, fields, (H, W), photos, grazing_deg,
                                       shadows and len(finished) < V * -(-L // lc), progress)
        del fields  # the photographs' phase holds no surface
        stage.release_freed_memory()
        enough = np.sum(weight > 0, axis=0) >= int(min_views) if int(min_views) > 1 else None
        bar = stage.Phase(progress, "photos to texels", V * L)
        for v, pv in enumerate(views):
            keep = np.ones(len(pv.idx), bool) if enough is None else enough[pv.idx]
            cam = photos.cameras[v]
            per_read = max(1, _READ_VALUES // max(1, cam.width * cam.height * C))
            lit_row = None if lit is None else np.searchsorted(lit[1], pv.idx)  # the camera's texels' rows of lit
            n_valid = 0
            for l0 in range(0, L, lc):
                l1 = min(l0 + lc, L)
                if (v, l0) in finished:  # converted by a killed run, kept
                    n_valid += finished[v, l0]
                    bar.advance(l1 - l0)
                    continue
                rad = np.empty((l1 - l0, len(pv.idx), C), np.float32)
                obs = np.empty((l1 - l0, len(pv.idx)), bool)
                for r0 in range(l0, l1, per_read):  # a few photographs at a time: ~_READ_VALUES floats
                    r1 = min(r0 + per_read, l1)
                    view = photos.read_view(v, lights=range(r0, r1))
                    if view.radiance.shape[-1] != C:
                        raise ValueError(f"{photos.folder}: camera {view.name} has {view.radiance.shape[-1]} "
                                         f"channels, camera {photos.names[0]} {C}")
                    img, ok_px = view.radiance.reshape(r1 - r0, -1, C), view.valid.reshape(r1 - r0, -1)
                    for t0 in range(0, len(pv.idx), _TAP_TEXELS):  # the four taps made a block at a time
                        t1 = min(t0 + _TAP_TEXELS, len(pv.idx))
                        rad[r0 - l0:r1 - l0, t0:t1], obs[r0 - l0:r1 - l0, t0:t1] = sample_taps(
                            img, ok_px, pv.taps(t0, t1), pv.weights[t0:t1])
                    del view, img, ok_px
                if lit is not None:
                    obs &= lit[0].unpack(l0, l1)[lit_row].T
                n_obs = int(obs.sum())
                n_valid += n_obs
                obs &= keep[None]
                rad[~obs] = 0.0
                _write_grid(writer, v, l0, l1, N, pv.cells, rad, obs)
                del rad, obs
                writer.checkpoint({"view": v, "light": l0, "valid": n_obs})
                stage.release_freed_memory()  # the chunk's photographs and samples, tens of MiB at 1024^2
                bar.advance(l1 - l0)
            valid_frac.append(n_valid / (len(pv.idx) * L) if len(pv.idx) else 0.0)
            lit_row = None
            views[v] = pv._replace(idx=None, cells=None, tap=None, weights=None)  # done with: dropped
        del lit, enough
        stage.release_freed_memory()
        surface = stage.texel_samples(mesh, resolution)
        report = PhotoTexelReport.of(surface, weight, [pv.rejected for pv in views], valid_frac, photos.names,
                                     grazing_deg=grazing_deg, min_views=min_views, shadows=shadows)
        writer.add_metadata({"photos": report.to_dict()})
    return surface, report


def photo_fingerprint(photos: PhotoCapture) -> str:
    """A SHA-256 over what a photo capture is: capture.json, the rig file and cameras.json (their bytes) and every
    photograph's and mask's name, size and modification time (not their pixels: a delivery is terabytes). Two
    captures with the same fingerprint are taken to be the same photographs."""
    h = hashlib.sha256()
    for f in (photos.folder / "capture.json", photos.rig_file, photos.cameras_file):
        h.update(str(f.name).encode() + b"\0")
        h.update(f.read_bytes() if f.is_file() else b"-")
    for v in range(photos.n_views):
        for f in [*photos.files(v), photos.mask_file(v)]:
            st = f.stat() if f is not None and f.is_file() else None
            h.update(f"{f}|{None if st is None else (st.st_size, st.st_mtime_ns)}\0".encode())
    return h.hexdigest()


def _mesh_digest(mesh: stage.Mesh) -> str:
    """A SHA-256 of the mesh's vertices, faces and UVs."""
    h = hashlib.sha256()
    for a in (mesh.vertices, mesh.faces, mesh.uv):
        h.update(b"-" if a is None else np.ascontiguousarray(np.asarray(a)).tobytes())
    return h.hexdigest()


def _write_grid(writer: CaptureStoreWriter, v: int, l0: int, l1: int, n_grid: int, cells: np.ndarray,
                rad: np.ndarray, obs: np.ndarray) -> None:
    """Write lights l0:l1 of view v over the whole grid of ``n_grid`` texels, in runs of ``_WRITE_TEXELS``:
    ``rad`` [Lc, n, C] and ``obs`` [Lc, n] at grid cells ``cells`` (increasing), zero and invalid elsewhere."""
    for s in range(0, n_grid, _WRITE_TEXELS):
        e = min(s + _WRITE_TEXELS, n_grid)
        a, b = np.searchsorted(cells, [s, e])
        out = np.zeros((l1 - l0, e - s, rad.shape[-1]), np.float32)
        ok = np.zeros((l1 - l0, e - s), bool)
        out[:, cells[a:b] - s] = rad[:, a:b]
        ok[:, cells[a:b] - s] = obs[:, a:b]
        writer.write(v, slice(l0, l1), slice(s, e), out, ok)

"""Photographs to a texel capture store, streamed: a delivery of any size resampled onto a mesh's texel grid
in bounded memory, written as the chunked store (``.zarr``) that ``relight fit`` streams from.

:func:`relight.io.photos_to_texels` builds the whole texel capture [V, L, P, C] in memory and reads each
camera's whole stack of photographs; one Light Stage X camera at 2048^2 is 346 x 4.2 M pixels x RGB, 17 GiB as
float32. Here a camera's photographs are read a light chunk at a time and every chunk of texels is written as
soon as it is complete, so memory is set by the chunk sizes (the light chunk's images and the texel grid's
per-texel geometry), not by the number of lights.
"""

from __future__ import annotations

import hashlib
import os

import numpy as np

import stage

from ._photo_texels import PhotoTexelReport, check_texel_arguments, sample_taps
from ._photos import PhotoCapture
from ._store import LIGHT_CHUNK, CaptureStoreWriter, default_chunks

# Texels per write: the grid is written in runs of this many texels, so no [Lc, H * W, C] array is built.
_WRITE_TEXELS = 1 << 18


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
        light_chunk: lights per read of a camera's photographs, and the store's light chunk (peak memory is
            about light_chunk x (image pixels + texels) x channels x 4 bytes).
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
    N, P, V, L = H * W, surface.num_samples, photos.n_views, photos.n_lights
    grid = np.asarray(surface.texel_index, np.int64)  # texel p's place in the H x W grid
    # Cast shadows, 1 bit per (texel, light); unpacked a light chunk at a time.
    lit = None
    occluder = stage.Occluder(mesh, surface)  # one BVH for every camera

    def project(v):
        return stage.project_texels(mesh, surface, photos.cameras[v], mask=photos.read_mask(v),
                                    grazing_deg=grazing_deg, occluder=occluder)

    enough = None
    if int(min_views) > 1:  # which texels enough cameras see, from the geometry alone, before any pixel is read
        counts = np.zeros(P, np.int64)
        for v in range(V):
            counts += project(v)[3]
        enough = counts >= int(min_views)
    C = photos.read_view(0, lights=[0]).radiance.shape[-1]
    lc = min(int(light_chunk), L)
    _, _, pc, _ = default_chunks((V, lc, N, C), np.float32)
    cameras = [stage.camera_to_dict(c, n) for c, n in zip(photos.cameras, photos.names, strict=True)]
    meta = {"space": "texel", "surface": {**dict(surface_info), "resolution": [int(H), int(W)]},
            "source": {"photo_capture": str(photos.folder)}}
    weight = np.zeros((V, P), np.float32)
    rejected, valid_frac = [], []
    of = {"photos": photo_fingerprint(photos), "mesh": _mesh_digest(mesh), "grazing_deg": float(grazing_deg),
          "min_views": int(min_views), "shadows": bool(shadows)}
    with CaptureStoreWriter(path, (V, L, N, C), np.float32, rig=photos.rig, cameras=cameras, metadata=meta,
                            chunks=(1, lc, pc, C), sample_shape=(H, W), partial=of, resume=resume) as writer:
        finished = {(int(e["view"]), int(e["light"])): int(e["valid"]) for e in writer.checkpoints
                    if writer.written(int(e["view"]), slice(int(e["light"]), min(int(e["light"]) + lc, L)))}
        if shadows and len(finished) < V * -(-L // lc):
            # Cast shadows, 1 bit per (texel, light); unpacked a light chunk at a time.
            lit = stage.light_visibility(mesh, surface, photos.rig, packed=True, progress=progress)
        bar = stage.Phase(progress, "photos to texels", V * L)
        for v in range(V):
            taps, w, cos_o, seen, reasons = project(v)
            idx = np.flatnonzero(seen)
            weight[v, idx] = cos_o[idx]
            rejected.append(reasons)
            t, wt = taps[idx], w[idx]
            keep = np.ones(len(idx), bool) if enough is None else enough[idx]
            n_valid = 0
            for l0 in range(0, L, lc):
                l1 = min(l0 + lc, L)
                if (v, l0) in finished:  # converted by a killed run, kept
                    n_valid += finished[v, l0]
                    bar.advance(l1 - l0)
                    continue
                view = photos.read_view(v, lights=range(l0, l1))
                if view.radiance.shape[-1] != C:
                    raise ValueError(f"{photos.folder}: camera {view.name} has {view.radiance.shape[-1]} channels, "
                                     f"camera {photos.names[0]} {C}")
                rad, obs = sample_taps(view.radiance.reshape(l1 - l0, -1, C), view.valid.reshape(l1 - l0, -1), t,
                                       wt)
                del view
                if lit is not None:
                    obs &= lit.unpack(l0, l1)[idx].T
                n_obs = int(obs.sum())
                n_valid += n_obs
                obs &= keep[None]
                _write_grid(writer, v, l0, l1, N, grid[idx], np.where(obs[..., None], rad, np.float32(0)), obs)
                writer.checkpoint({"view": v, "light": l0, "valid": n_obs})
                bar.advance(l1 - l0)
            valid_frac.append(n_valid / (len(idx) * L) if len(idx) else 0.0)
        report = PhotoTexelReport.of(surface, weight, rejected, valid_frac, photos.names, grazing_deg=grazing_deg,
                                     min_views=min_views, shadows=shadows)
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
    ``rad`` [Lc, n, C] and ``obs`` [Lc, n] at grid cells ``cells`` (sorted), zero and invalid elsewhere."""
    order = np.argsort(cells, kind="stable")
    cells, rad, obs = cells[order], rad[:, order], obs[:, order]
    for s in range(0, n_grid, _WRITE_TEXELS):
        e = min(s + _WRITE_TEXELS, n_grid)
        a, b = np.searchsorted(cells, [s, e])
        out = np.zeros((l1 - l0, e - s, rad.shape[-1]), np.float32)
        ok = np.zeros((l1 - l0, e - s), bool)
        out[:, cells[a:b] - s] = rad[:, a:b]
        ok[:, cells[a:b] - s] = obs[:, a:b]
        writer.write(v, slice(l0, l1), slice(s, e), out, ok)

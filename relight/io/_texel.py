"""Texel-space data on disk back to the objects the library works with: a
capture folder to ``stage.Capture`` + ``stage.Surface``, a map set to
``relight.MaterialMaps`` over the same surface.

Both record how to rebuild their texel surface (``mesh_spec``): the capture in
``capture.json``'s ``metadata`` (``{"space": "texel", "surface": spec}``, as
``relight simulate`` writes), the map set in ``maps.json``'s ``surface``. A
spec is ``{"bundled": "head" | None, "path", "scale", "center", "resolution"}``:
the bundled head (``stage.load_head``: scaled to mm and centred) or a mesh file
with the scale (mm per file unit) and centring it is placed with.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Mapping
from pathlib import Path
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

import stage

from ..materials._maps import MaterialMaps
from ._capture import CaptureReader, open_capture
from ._errors import ImageFormatError
from ._store import is_capture_store
from ._store_reader import open_capture_store
from ._texture_set import TextureSet, read_maps

__all__ = ["SampleSubset", "TexelCapture", "TexelMaps", "load_texel_capture", "load_texel_maps", "mesh_size_warning",
           "mesh_spec", "open_texel_capture", "spec_mesh", "texel_surface", "MESH_UNITS"]


# Length units a mesh file may be in, as millimetres per unit (stage's one table).
MESH_UNITS = stage.LENGTH_UNITS_MM
# A mesh whose bounding-box diagonal is outside this fraction of the rig's
# radius is implausible: a face fills 10-40% of a light stage; below 5% it is
# almost surely in other units, above 150% it does not fit inside the lights.
_PLAUSIBLE_EXTENT = (0.05, 1.5)


def _same_file(a: Path, b: Path) -> bool:
    try:
        if a.stat().st_size != b.stat().st_size:
            return False
        return hashlib.sha256(a.read_bytes()).digest() == hashlib.sha256(b.read_bytes()).digest()
    except OSError:
        return False


def mesh_spec(path: str | os.PathLike | None = None, *, units: str | None = None, scale: float | None = None,
              center: bool | None = None) -> dict:
    """How to load a mesh again, and how to place it in the stage frame (mm).

    ``path``: ``None``, ``"head"`` or ``"bundled"`` for the bundled head, else
    a mesh file (made absolute). ``units`` ("mm", "cm", "m": the file's length
    unit) or ``scale`` (mm per file unit; not both) and ``center`` (move the
    bounding-box centre to the rig centre) say how to place it. Defaults: a
    file in mm, as is; the bundled head scan, and a byte-identical copy of it
    given as a file, get the scan's own placement (x ``stage.HEAD_SCALE_MM``,
    centred), so the same file gives the same mesh however it is named.
    FileNotFoundError naming a missing file; ValueError naming a bad argument."""
    if units is not None and scale is not None:
        raise ValueError(f"mesh: give units ({units!r}) or scale ({scale!r}), not both")
    if units is not None and units not in MESH_UNITS:
        raise ValueError(f"mesh: units must be one of {sorted(MESH_UNITS)}, got {units!r}")
    if scale is not None and not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"mesh: scale must be a positive finite number (mm per file unit), got {scale!r}")
    head = stage.head_mesh_path()
    if path is None or str(path) in ("head", "bundled"):
        p, known = head, True
    else:
        p = Path(path).resolve()
        if not p.is_file():
            raise FileNotFoundError(f"{path}: mesh file not found")
        known = _same_file(p, head)
    placed = units is not None or scale is not None or center is not None
    mm = MESH_UNITS[units] if units is not None else scale
    if known:
        spec = {"bundled": "head" if p == head and not placed else None, "path": str(p),
                "scale": float(stage.HEAD_SCALE_MM if mm is None else mm), "center": True if center is None else center}
    else:
        spec = {"bundled": None, "path": str(p), "scale": float(1.0 if mm is None else mm), "center": bool(center)}
    return spec


def mesh_size_warning(mesh: stage.Mesh, rig: stage.Rig) -> str | None:
    """A one-line warning when ``mesh`` (mm) is implausibly small or large for
    ``rig`` (its bounding-box diagonal against the rig's median light distance,
    near-field rigs only), naming the sizes and the flags that fix it; else None."""
    if not rig.near_field:
        return None
    v = np.asarray(mesh.vertices, np.float64)
    extent = float(np.linalg.norm(v.max(0) - v.min(0)))
    radius = float(np.median(np.linalg.norm(np.asarray(rig.position, np.float64), axis=1)))
    lo, hi = _PLAUSIBLE_EXTENT
    if lo * radius <= extent <= hi * radius:
        return None
    return (f"mesh '{mesh.name}' is {extent:.3g} mm across but the rig's lights are {radius:.4g} mm away: "
            "if the mesh is not in mm, say its units (--units mm|cm|m or --scale MM_PER_UNIT)")


def spec_mesh(spec: Mapping, where: str = "") -> stage.Mesh:
    """The mesh a :func:`mesh_spec` describes (with UVs). ``where`` (the file the
    spec was read from) starts the error messages."""
    if not isinstance(spec, Mapping) or "path" not in spec:
        raise ImageFormatError(f"{where}: no mesh recorded (expected a 'surface' entry with the mesh 'path')")
    if spec.get("bundled") == "head":
        return stage.load_head()
    path = Path(spec["path"])
    if not path.is_file():
        raise FileNotFoundError(f"{path}: mesh file not found (recorded in {where})")
    try:
        scale, center = float(spec.get("scale", 1.0)), bool(spec.get("center", False))
    except (TypeError, ValueError):
        raise ImageFormatError(f"{where}: field 'scale' must be a number, got {spec.get('scale')!r}") from None
    return stage.load_mesh(path, scale=scale, center=center, require_uv=True)


def texel_surface(spec: Mapping, resolution, where: str = "") -> tuple[stage.Mesh, stage.Surface]:
    """``(mesh, full texel surface)`` for a recorded mesh spec and texel
    resolution (``N`` or ``[H, W]``), as ``stage.texel_samples`` builds it."""
    mesh = spec_mesh(spec, where)
    try:
        res = tuple(int(r) for r in (resolution if np.ndim(resolution) else (resolution, resolution)))
    except (TypeError, ValueError):
        raise ImageFormatError(f"{where}: bad texel resolution {resolution!r}") from None
    return mesh, stage.texel_samples(mesh, res)


class TexelCapture(NamedTuple):
    """What :func:`load_texel_capture` and :func:`open_texel_capture` return (unpacks as a 4-tuple)."""

    capture: stage.Capture  # over the texels with at least one valid observation (open_texel_capture: a SampleSubset)
    surface: stage.Surface  # those texels (a subset of the full texel grid)
    mesh: stage.Mesh
    metadata: dict  # capture.json's metadata; metadata["surface"] is the mesh spec


class SampleSubset:
    """A capture source restricted to some of its samples, read lazily: a
    ``relight.io.CaptureSource`` (``read`` / ``read_mask`` take all views and
    lights and a slice of the subset's samples), what :func:`relight.fit`
    streams from.

    ``source``: a capture store (``relight.io.open_capture_store``) or a
    capture folder (``relight.io.open_capture``); ``index``: the source's
    sample indices, strictly increasing; sample i of the view is sample
    ``index[i]`` of the source. A store is read in runs of contiguous indices
    (neighbouring runs merged while their span stays within ``max(2 n,
    store sample chunk)`` for n selected samples, so memory is bounded by a
    few times the selection); a folder one image at a time (each EXR is
    decoded whole: a folder is the slow path). Radiance comes back float32.
    ``rig`` / ``cameras`` are the source's as ``stage`` objects."""

    def __init__(self, source, index):
        idx = np.asarray(index, np.int64).reshape(-1)
        V, L, P, C = (int(s) for s in source.shape)
        if idx.size == 0 or idx.min() < 0 or idx.max() >= P or np.any(np.diff(idx) <= 0):
            raise ValueError(f"SampleSubset: index must be non-empty, strictly increasing and in [0, {P})")
        self.source, self.index = source, idx
        self.shape = (V, L, int(idx.size), C)
        self.n_views, self.n_lights, self.n_samples, self.n_channels = self.shape
        # A folder decodes each light image whole: read it once per image, not once per run.
        self._store = not isinstance(source, CaptureReader)
        self._rig = self._cameras = None

    def __repr__(self) -> str:
        return f"SampleSubset({self.source!r}, {self.n_samples} of {self.source.shape[2]} samples)"

    @property
    def rig(self) -> stage.Rig:
        if self._rig is None:
            self._rig = self.source.stage_rig()
        return self._rig

    @property
    def cameras(self) -> tuple[stage.Camera, ...]:
        if self._cameras is None:
            self._cameras = tuple(self.source.stage_cameras())
        return self._cameras

    def stage_rig(self) -> stage.Rig:
        return self.rig

    def stage_cameras(self) -> tuple[stage.Camera, ...]:
        return self.cameras

    def _selected(self, samples) -> np.ndarray:
        if samples is None:
            return self.index
        if not isinstance(samples, slice) or samples.step not in (None, 1):
            raise ValueError(f"SampleSubset: samples must be None or a slice with step 1, got {samples!r}")
        s, e, _ = samples.indices(self.n_samples)
        if e <= s:
            raise ValueError(f"SampleSubset: samples {samples!r} selects nothing of {self.n_samples}")
        return self.index[s:e]

    def _runs(self, idx: np.ndarray):
        """(start, stop, positions) spans of the source covering ``idx``, each at most max(2 n, chunk) long."""
        limit = max(2 * len(idx), int(getattr(self.source, "chunks", (0, 0, 1))[2]))
        i = 0
        while i < len(idx):
            j = int(np.searchsorted(idx, idx[i] + limit, side="left"))
            yield int(idx[i]), int(idx[j - 1]) + 1, i, j
            i = j

    def read(self, views=None, lights=None, samples=None) -> tuple[np.ndarray, np.ndarray]:
        """``(radiance [V, L, n, C] float32, mask [V, L, n] bool)`` of the selected samples (all views and
        lights: ``views`` / ``lights`` must be None)."""
        if views is not None or lights is not None:
            raise ValueError("SampleSubset.read: reads every view and light (views / lights must be None)")
        idx = self._selected(samples)
        V, L, _, C = self.shape
        rad = np.empty((V, L, len(idx), C), np.float32)
        msk = np.empty((V, L, len(idx)), bool)
        if self._store:
            for a, b, i, j in self._runs(idx):
                r, m = self.source.read(samples=slice(a, b))
                rad[:, :, i:j] = r[:, :, idx[i:j] - a]
                msk[:, :, i:j] = m[:, :, idx[i:j] - a]
            return rad, msk
        lo, hi = int(idx[0]), int(idx[-1]) + 1
        for v in range(V):
            for light in range(L):
                r, m = self.source.read(views=v, lights=light, samples=slice(lo, hi))
                rad[v, light] = r[0, 0, idx - lo]
                msk[v, light] = m[0, 0, idx - lo]
        return rad, msk

    def read_mask(self, views=None, lights=None, samples=None) -> np.ndarray:
        """The mask [V, L, n] of the selected samples (``views`` / ``lights`` must be None); a store
        decodes no radiance, a folder without a valid channel reads no file."""
        if views is not None or lights is not None:
            raise ValueError("SampleSubset.read_mask: reads every view and light (views / lights must be None)")
        if not self._store:
            if not self.source.has_valid:
                return np.ones((*self.shape[:2], len(self._selected(samples))), bool)
            return self.read(samples=samples)[1]
        idx = self._selected(samples)
        V, L, _, _ = self.shape
        msk = np.empty((V, L, len(idx)), bool)
        for a, b, i, j in self._runs(idx):
            msk[:, :, i:j] = self.source.read_mask(samples=slice(a, b))[:, :, idx[i:j] - a]
        return msk


def _open_texel(folder):
    """(reader, is_store, where, mesh, full surface) of a texel capture folder or store, checked."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such capture folder")
    store = not (folder / "capture.json").exists() and is_capture_store(folder)
    reader = open_capture_store(folder) if store else open_capture(folder)
    where = str(reader.manifest_path if store else folder / "capture.json")
    info = reader.metadata.get("surface")
    if reader.metadata.get("space") != "texel" or not isinstance(info, Mapping):
        raise ImageFormatError(f"{where}: not a texel-space capture (metadata.space = 'texel' and metadata.surface, "
                               "as `relight simulate` writes, are needed to rebuild the surface)")
    mesh, full = texel_surface(info, info.get("resolution"), where=where)
    if tuple(full.resolution) != tuple(reader.sample_shape):
        raise ImageFormatError(f"{where}: images are {reader.sample_shape} but the texel grid is {full.resolution}")
    return reader, store, where, mesh, full


def load_texel_capture(folder: str | os.PathLike, progress: stage.Progress | None = None) -> TexelCapture:
    """A texel-space capture folder (``relight simulate``'s) as a
    ``stage.Capture`` over the texels it observes, their ``stage.Surface``, the
    mesh and the capture's metadata.

    The surface is rebuilt from ``metadata["surface"]`` (mesh, scale, centring,
    resolution) and must match the stored image size; texels with no valid
    observation in any view under any light are dropped. The rig and cameras
    are read with ``stage.rig_from_dict`` / ``stage.camera_from_dict`` (either
    schema those have had). ``progress(phase, done, total)`` (``stage.Progress``)
    counts the light images read, phase "read capture".

    ``folder`` may also be a capture store (``relight.io.open_capture_store``:
    a ``.zarr`` folder, read one sample chunk at a time, progress counting
    sample chunks). The whole capture ends up in memory:
    :func:`open_texel_capture` is the streaming counterpart.

    Raises FileNotFoundError or ImageFormatError / ValueError naming the file
    and the problem.
    """
    folder = Path(folder)
    reader, store, where, mesh, full = _open_texel(folder)
    rig = reader.stage_rig()
    cams = reader.stage_cameras()
    idx = np.asarray(full.texel_index)
    V, L = reader.n_views, reader.n_lights
    if store:
        rad, valid = reader.gather_samples(idx, progress=progress)
    else:
        rad = np.zeros((V, L, len(idx), reader.n_channels), np.float32)
        valid = np.zeros((V, L, len(idx)), bool)
        bar = stage.Phase(progress, "read capture", V * L)
        for v in range(V):
            for light, r, m in reader.iter_lights(v):
                rad[v, light] = r[idx]
                valid[v, light] = True if m is None else m[idx]
                bar.advance(1)
    keep = np.nonzero(valid.any(axis=(0, 1)))[0]
    if len(keep) == 0:
        raise ImageFormatError(f"{folder}: no valid observation on any texel of the mesh")
    capture = stage.Capture(radiance=jnp.asarray(rad[:, :, keep]), mask=jnp.asarray(valid[:, :, keep]), rig=rig,
                            cameras=cams)
    return TexelCapture(capture, full.take(keep), mesh, dict(reader.metadata))


def _seen(reader, store: bool, idx: np.ndarray, progress) -> np.ndarray:
    """[len(idx)] bool: the texels ``idx`` with a valid observation in some view under some light, from
    the mask only (a store's mask array, one sample chunk at a time; a folder's valid channels, one image
    at a time; a folder without them: every texel)."""
    if not reader.has_valid:
        return np.ones(len(idx), bool)
    seen = np.zeros(len(idx), bool)
    if store:
        n = reader.chunks[2]
        bar = stage.Phase(progress, "read mask", -(-reader.n_samples // n))
        for s in range(0, reader.n_samples, n):
            e = min(s + n, reader.n_samples)
            here = np.nonzero((idx >= s) & (idx < e))[0]
            if here.size:
                seen[here] = reader.read_mask(samples=slice(s, e)).any(axis=(0, 1))[idx[here] - s]
            bar.advance(1)
        return seen
    bar = stage.Phase(progress, "read mask", reader.n_views * reader.n_lights)
    for v in range(reader.n_views):
        for light in range(reader.n_lights):
            _, m = reader.read_image(v, light)
            seen |= m[idx]
            bar.advance(1)
    return seen


def open_texel_capture(folder: str | os.PathLike, progress: stage.Progress | None = None) -> TexelCapture:
    """:func:`load_texel_capture` without loading the capture: the same surface,
    mesh and metadata, and as ``capture`` a :class:`SampleSubset` of the folder
    or store over the same texels (those with a valid observation), which
    :func:`relight.fit` / ``relight.fitting.fit_parts`` read one block at a
    time. Finding those texels reads the mask only (a store's mask array; a
    folder's images, once); ``progress`` counts it, phase "read mask".
    Raises as :func:`load_texel_capture`."""
    folder = Path(folder)
    reader, store, _, mesh, full = _open_texel(folder)
    idx = np.asarray(full.texel_index, np.int64)
    keep = np.nonzero(_seen(reader, store, idx, progress))[0]
    if len(keep) == 0:
        raise ImageFormatError(f"{folder}: no valid observation on any texel of the mesh")
    return TexelCapture(SampleSubset(reader, idx[keep]), full.take(keep), mesh, dict(reader.metadata))


class TexelMaps(NamedTuple):
    """What :func:`load_texel_maps` returns."""

    textures: TextureSet
    maps: MaterialMaps  # over ``surface``
    surface: stage.Surface  # the covered texels
    mesh: stage.Mesh
    cameras: tuple[stage.Camera, ...]  # maps.json metadata "cameras" (those of the fitted capture), maybe ()
    rig: stage.Rig | None  # the rig file maps.json metadata "rig" names (the fitted capture's), if any


def load_texel_maps(folder: str | os.PathLike) -> TexelMaps:
    """A map set (``relight.io.write_maps``'s) with the texel surface rebuilt
    from ``maps.json``'s ``surface`` entry and the maps at its covered texels
    (and at its filled ones, which no camera saw: ``TextureSet.filled``);
    also the cameras and rig the set's metadata records (``relight fit`` keeps
    the capture's). Raises as :func:`relight.io.read_maps`, naming the file."""
    folder = Path(folder)
    textures, info = read_maps(folder)
    where = str(folder / "maps.json")
    mesh, full = texel_surface(info, textures.resolution, where=where)
    # The texels that hold a sample's maps: measured (coverage) or the fill of texels no camera saw (filled).
    cov = (textures.coverage | textures.filled).reshape(-1)[np.asarray(full.texel_index)]
    surface = full.subset(np.nonzero(cov)[0])
    meta = textures.info.get("metadata", {})
    docs = meta.get("cameras") or []
    if not isinstance(docs, list):
        raise ImageFormatError(f"{where}: field 'metadata.cameras' must be a list of cameras")
    cameras = tuple(stage.camera_from_dict(c, f"{where}: metadata.cameras[{i}]") for i, c in enumerate(docs))
    rig = None
    if meta.get("rig") and (folder / str(meta["rig"])).is_file():
        rig = stage.load_rig(folder / str(meta["rig"]))
    return TexelMaps(textures, textures.maps(surface), surface, mesh, cameras, rig)

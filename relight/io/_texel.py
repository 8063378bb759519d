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
from ._capture import open_capture
from ._errors import ImageFormatError
from ._store import is_capture_store, open_capture_store
from ._texture_set import TextureSet, read_maps

__all__ = ["TexelCapture", "TexelMaps", "load_texel_capture", "load_texel_maps", "mesh_size_warning", "mesh_spec",
           "spec_mesh", "texel_surface", "MESH_UNITS"]


# Length units a mesh file may be in, as millimetres per unit.
MESH_UNITS = {"mm": 1.0, "cm": 10.0, "m": 1000.0}
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
    """What :func:`load_texel_capture` returns (unpacks as a 4-tuple)."""

    capture: stage.Capture  # over the texels with at least one valid observation
    surface: stage.Surface  # those texels (a subset of the full texel grid)
    mesh: stage.Mesh
    metadata: dict  # capture.json's metadata; metadata["surface"] is the mesh spec


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
    sample chunks).

    Raises FileNotFoundError or ImageFormatError / ValueError naming the file
    and the problem.
    """
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
    rig = reader.stage_rig()
    cams = reader.stage_cameras()
    mesh, full = texel_surface(info, info.get("resolution"), where=where)
    if tuple(full.resolution) != tuple(reader.sample_shape):
        raise ImageFormatError(f"{where}: images are {reader.sample_shape} but the texel grid is {full.resolution}")
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
    return TexelCapture(capture, full.subset(keep), mesh, dict(reader.metadata))


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
    from ``maps.json``'s ``surface`` entry and the maps at its covered texels;
    also the cameras and rig the set's metadata records (``relight fit`` keeps
    the capture's). Raises as :func:`relight.io.read_maps`, naming the file."""
    folder = Path(folder)
    textures, info = read_maps(folder)
    where = str(folder / "maps.json")
    mesh, full = texel_surface(info, textures.resolution, where=where)
    cov = textures.coverage.reshape(-1)[np.asarray(full.texel_index)]
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

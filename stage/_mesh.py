"""Triangle meshes loaded with trimesh and checked at the boundary."""

from __future__ import annotations

import dataclasses
from importlib import resources
from pathlib import Path

import numpy as np
import trimesh

# Lee Perry-Smith scan units -> mm: puts the ear-to-ear width at ~21 cm and the
# crown-to-neck height at ~20 cm, an adult head.
HEAD_SCALE_MM = 25.0


@dataclasses.dataclass(frozen=True)
class Mesh:
    """Vertices [N, 3] (mm), faces [F, 3], per-vertex normals [N, 3] and UVs [N, 2] (or None)."""

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    uv: np.ndarray | None
    name: str = "mesh"

    def trimesh(self) -> trimesh.Trimesh:
        return trimesh.Trimesh(self.vertices, self.faces, vertex_normals=self.normals, process=False)


def load_mesh(path, scale: float = 1.0, center: bool = False, require_uv: bool = False) -> Mesh:
    """Load an OBJ/PLY/GLB mesh with trimesh, multiply positions by ``scale``
    (to mm), optionally move its bounding-box centre to the origin.

    Normals missing from the file are computed (area-weighted); degenerate
    (zero-area) faces are dropped. Raises ValueError naming the file when it has
    no triangles, or no UVs while ``require_uv``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"mesh file not found: {path}")
    try:
        loaded = trimesh.load(str(path), process=False)
    except Exception as exc:  # trimesh raises many types for bad files
        raise ValueError(f"{path}: not a readable mesh ({exc})") from exc
    if isinstance(loaded, trimesh.Scene):
        if not loaded.geometry:
            raise ValueError(f"{path}: the file holds no geometry")
        loaded = loaded.to_geometry()
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise ValueError(f"{path}: no triangles found")
    uv = getattr(loaded.visual, "uv", None)
    if uv is not None and len(uv) != len(loaded.vertices):
        uv = None
    if require_uv and uv is None:
        raise ValueError(f"{path}: mesh has no UV coordinates, which texel-space sampling needs")
    verts = np.asarray(loaded.vertices, dtype=np.float64) * float(scale)
    if center:
        verts = verts - 0.5 * (verts.min(0) + verts.max(0))
    faces = np.asarray(loaded.faces, dtype=np.int64)
    area2 = np.linalg.norm(np.cross(verts[faces[:, 1]] - verts[faces[:, 0]], verts[faces[:, 2]] - verts[faces[:, 0]]), axis=1)
    faces = faces[area2 > 0]
    if len(faces) == 0:
        raise ValueError(f"{path}: every face is degenerate")
    # trimesh returns the file's normals when it has them, else area-weighted ones.
    normals = np.asarray(loaded.vertex_normals, dtype=np.float64)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    if normals.shape != verts.shape or np.any(length < 1e-12):
        normals = np.asarray(trimesh.Trimesh(verts, faces, process=False).vertex_normals, dtype=np.float64)
        length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = normals / np.maximum(length, 1e-12)
    return Mesh(vertices=verts, faces=faces, normals=normals,
                uv=None if uv is None else np.asarray(uv, dtype=np.float64), name=path.stem)


def head_mesh_path() -> Path:
    """Path of the bundled Lee Perry-Smith head scan (CC-BY 3.0, Infinite Realities)."""
    return Path(str(resources.files("stage.data").joinpath("lee_perry_smith_head.glb")))


def load_head() -> Mesh:
    """The bundled head scan in mm, centred on the rig centre, facing +z."""
    return load_mesh(head_mesh_path(), scale=HEAD_SCALE_MM, center=True, require_uv=True)

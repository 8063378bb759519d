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
    # Indices (in the file's face order) of the zero-area faces load_mesh dropped.
    dropped_faces: np.ndarray | None = dataclasses.field(default=None, compare=False, repr=False)

    def trimesh(self) -> trimesh.Trimesh:
        """The mesh as a ``trimesh.Trimesh`` (no processing: indices kept)."""
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
    e1, e2 = verts[faces[:, 1]] - verts[faces[:, 0]], verts[faces[:, 2]] - verts[faces[:, 0]]
    area2 = np.linalg.norm(np.cross(e1, e2), axis=1)
    dropped = np.nonzero(~(area2 > 0))[0]
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
                uv=None if uv is None else np.asarray(uv, dtype=np.float64), name=path.stem,
                dropped_faces=dropped)


def head_mesh_path() -> Path:
    """Path of the bundled Lee Perry-Smith head scan (CC-BY 3.0, Infinite Realities)."""
    return Path(str(resources.files("stage.data").joinpath("lee_perry_smith_head.glb")))


def load_head() -> Mesh:
    """The bundled head scan in mm, centred on the rig centre, facing +z."""
    return load_mesh(head_mesh_path(), scale=HEAD_SCALE_MM, center=True, require_uv=True)


@dataclasses.dataclass(frozen=True)
class MeshReport:
    """What ``check_mesh`` found: counts, and the indices of the offending faces
    or vertices (empty arrays when clean)."""

    num_vertices: int
    num_faces: int
    degenerate_faces: np.ndarray  # zero (or < area_tol) area faces
    repeated_index_faces: np.ndarray  # faces naming one vertex twice
    out_of_range_faces: np.ndarray  # faces with an index outside [0, N)
    nonfinite_vertices: np.ndarray
    bad_normals: np.ndarray  # vertices whose normal is not unit length (tolerance 1e-3)
    has_uv: bool
    dropped_on_load: int  # degenerate faces load_mesh already removed

    @property
    def ok(self) -> bool:
        """True when nothing above needs attention."""
        return not (len(self.degenerate_faces) or len(self.repeated_index_faces) or len(self.out_of_range_faces)
                    or len(self.nonfinite_vertices) or len(self.bad_normals))

    def summary(self) -> str:
        """One line per problem, naming counts and the first few indices."""
        lines = [f"{self.num_vertices} vertices, {self.num_faces} faces, uv: {'yes' if self.has_uv else 'no'}"]
        problems = ("degenerate_faces", "repeated_index_faces", "out_of_range_faces", "nonfinite_vertices",
                    "bad_normals")
        for name in problems:
            idx = getattr(self, name)
            if len(idx):
                lines.append(f"{name.replace('_', ' ')}: {len(idx)} (first: {idx[:5].tolist()})")
        if self.dropped_on_load:
            lines.append(f"degenerate faces dropped on load: {self.dropped_on_load}")
        return "\n".join(lines)


def check_mesh(mesh: Mesh, area_tol: float = 0.0, require_uv: bool = False) -> MeshReport:
    """Validate a mesh: degenerate faces (area <= ``area_tol`` mm^2), faces with
    repeated or out-of-range indices, non-finite vertices, non-unit normals.
    Returns a MeshReport; raises ValueError only when ``require_uv`` and the mesh
    has no UVs (texel-space sampling needs them)."""
    V = np.asarray(mesh.vertices, np.float64)
    F = np.asarray(mesh.faces, np.int64)
    if require_uv and mesh.uv is None:
        raise ValueError(f"mesh '{mesh.name}' has no UV coordinates; texel-space sampling needs them")
    oor = np.nonzero(np.any((F < 0) | (F >= len(V)), axis=1))[0]
    Fc = np.clip(F, 0, max(len(V) - 1, 0))
    rep = np.nonzero((F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 0] == F[:, 2]))[0]
    tri = V[Fc]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    degenerate = np.nonzero(~(area > area_tol))[0]
    nonfinite = np.nonzero(~np.all(np.isfinite(V), axis=1))[0]
    nl = np.linalg.norm(np.asarray(mesh.normals, np.float64), axis=1)
    bad_n = np.nonzero(~(np.abs(nl - 1) < 1e-3))[0]
    dropped = 0 if mesh.dropped_faces is None else len(mesh.dropped_faces)
    return MeshReport(len(V), len(F), degenerate, rep, oor, nonfinite, bad_n, mesh.uv is not None, dropped)

"""Triangle meshes loaded with trimesh and checked at the boundary."""

from __future__ import annotations

import dataclasses
from importlib import resources
from pathlib import Path

import numpy as np
import trimesh

# Lee Perry-Smith scan units -> mm: an adult head. Per scan unit the scan measures 4.7 crown to chin, 3.6 ear
# to ear and 4.5 nose tip to back; adult men measure about 230, 155 and 215 mm (the last with the nose), so
# 46 mm per unit puts each within about 7% (217, 166 and 209 mm; the shoulders' 8.6 units become 394 mm).
HEAD_SCALE_MM = 46.0

# Millimetres per length unit, for every file that names its unit (meshes, rig files, camera calibrations).
LENGTH_UNITS_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0}

# The largest coordinate (mm, after ``scale``) load_mesh accepts: 1000 km, far beyond any stage, and small
# enough that squares (1e18: areas, squared distances) and cubes (1e27) stay well inside float32's 3.4e38.
# A mesh in the wrong unit by 1e35 would otherwise give Inf areas and NaN normals deep inside sampling.
MAX_COORDINATE_MM = 1e9


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
    """Load an OBJ/PLY/GLB mesh with trimesh.

    Normals missing from the file are computed (area-weighted); degenerate (zero-area) faces are dropped.

    Args:
        path: the mesh file.
        scale: factor taking the file's positions to mm.
        center: move the bounding-box centre to the origin.
        require_uv: refuse a mesh without UVs.

    Returns:
        The ``Mesh``.

    Raises:
        ValueError: naming the file, when it is not a readable mesh, has no triangles, a face index out of range,
            a NaN / Inf vertex or UV, a coordinate beyond ``MAX_COORDINATE_MM`` (after ``scale``), or no UVs while
            ``require_uv``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"mesh file not found: {path}")
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"load_mesh: argument 'scale' must be positive and finite, got {scale!r}")
    loaded = _load(path)
    uv = getattr(loaded.visual, "uv", None)
    if uv is not None and len(uv) != len(loaded.vertices):
        uv = None
    if require_uv and uv is None:
        raise ValueError(f"{path}: mesh has no UV coordinates, which texel-space sampling needs")
    verts, faces = _checked_geometry(loaded, float(scale), path)
    if uv is not None:
        uv = np.asarray(uv, dtype=np.float64)
        bad = np.nonzero(~np.all(np.isfinite(uv), axis=1))[0]
        if len(bad):
            raise ValueError(f"{path}: {len(bad)} UV coordinate(s) are NaN or Inf (first: vertex {int(bad[0])})")
    if center:
        verts = verts - 0.5 * (verts.min(0) + verts.max(0))
    e1, e2 = verts[faces[:, 1]] - verts[faces[:, 0]], verts[faces[:, 2]] - verts[faces[:, 0]]
    area2 = np.linalg.norm(np.cross(e1, e2), axis=1)
    dropped = np.nonzero(~(area2 > 0))[0]
    faces = faces[area2 > 0]
    if len(faces) == 0:
        raise ValueError(f"{path}: every face is degenerate")
    # trimesh returns the file's normals when it has them, else area-weighted ones.
    normals = np.asarray(loaded.vertex_normals, dtype=np.float64)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    if normals.shape != verts.shape or not np.all((length >= 1e-12) & np.isfinite(length)):  # zero, NaN, Inf
        normals = np.asarray(trimesh.Trimesh(verts, faces, process=False).vertex_normals, dtype=np.float64)
        length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = normals / np.maximum(length, 1e-12)
    return Mesh(vertices=verts, faces=faces, normals=normals, uv=uv, name=path.stem, dropped_faces=dropped)


def _load(path: Path) -> trimesh.Trimesh:
    """The file's triangles as one Trimesh (ValueError naming the file otherwise)."""
    try:
        loaded = trimesh.load(str(path), process=False)
        if isinstance(loaded, trimesh.Scene):
            if not loaded.geometry:
                raise ValueError(f"{path}: the file holds no geometry")
            loaded = loaded.to_geometry()
    except MemoryError:
        raise
    except Exception as exc:  # trimesh raises many types for bad files (and names none of them)
        if isinstance(exc, ValueError) and str(exc).startswith(str(path)):
            raise
        raise ValueError(f"{path}: not a readable mesh ({type(exc).__name__}: {exc})") from exc
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise ValueError(f"{path}: no triangles found")
    return loaded


def _checked_geometry(loaded: trimesh.Trimesh, scale: float, path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(vertices [N, 3] mm, faces [F, 3] int64), refusing what would poison sampling: a face index
    outside the vertices, a NaN / Inf vertex, a coordinate beyond MAX_COORDINATE_MM."""
    verts = np.asarray(loaded.vertices, dtype=np.float64)
    faces = np.asarray(loaded.faces, dtype=np.int64)
    if verts.ndim != 2 or verts.shape[1] != 3 or len(verts) == 0:
        raise ValueError(f"{path}: vertex positions must be [N, 3] with N >= 1, got shape {verts.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or np.any((faces < 0) | (faces >= len(verts))):
        raise ValueError(f"{path}: face indices must be triangles of vertices 0..{len(verts) - 1}")
    bad = np.nonzero(~np.all(np.isfinite(verts), axis=1))[0]
    if len(bad):
        raise ValueError(f"{path}: {len(bad)} vertex position(s) are NaN or Inf (first: vertex {int(bad[0])})")
    verts = verts * scale
    top = float(np.abs(verts).max(initial=0.0))
    if top > MAX_COORDINATE_MM:
        raise ValueError(f"{path}: a vertex coordinate is {top:.3g} mm (after scale {scale:g}), beyond the "
                         f"limit of {MAX_COORDINATE_MM:.0e} mm (stage.MAX_COORDINATE_MM): wrong units?")
    return verts, faces


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
    """Validate a mesh: degenerate faces, repeated or out-of-range indices, non-finite vertices, non-unit normals.

    Args:
        mesh: the mesh.
        area_tol: faces with an area <= this (mm^2) count as degenerate.
        require_uv: refuse a mesh without UVs (texel-space sampling needs them).

    Returns:
        The ``MeshReport``.

    Raises:
        ValueError: only when ``require_uv`` and the mesh has no UVs.
    """
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


def uv_sphere(radius: float = 50.0, n_lat: int = 48, n_lon: int = 96, center=(0.0, 0.0, 0.0),
              with_uv: bool = True) -> Mesh:
    """A latitude-longitude sphere mesh with an equirectangular UV map (a seam at u = 0).

    Args:
        radius: the radius in mm, > 0.
        n_lat, n_lon: the rings from pole to pole and the segments around the y axis (>= 2, >= 3).
        center: the centre [3] in mm.
        with_uv: False: a mesh without UVs.

    Returns:
        A ``Mesh`` with its analytic vertex normals; the zero-area triangles at the poles are dropped.
    """
    if not radius > 0 or n_lat < 2 or n_lon < 3:
        raise ValueError(f"uv_sphere: need radius > 0, n_lat >= 2, n_lon >= 3, got {radius}, {n_lat}, {n_lon}")
    th = np.linspace(0, np.pi, n_lat + 1)
    ph = np.linspace(0, 2 * np.pi, n_lon + 1)
    T, Pp = np.meshgrid(th, ph, indexing="ij")
    n = np.stack([np.sin(T) * np.cos(Pp), np.cos(T), np.sin(T) * np.sin(Pp)], -1).reshape(-1, 3)
    verts = radius * n + np.asarray(center)
    uv = np.stack([Pp.ravel() / (2 * np.pi), 1 - T.ravel() / np.pi], 1)
    idx = np.arange((n_lat + 1) * (n_lon + 1)).reshape(n_lat + 1, n_lon + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)])
    v = verts[faces]
    keep = np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1) > 1e-9
    return Mesh(verts, faces[keep], n, uv if with_uv else None, "sphere")

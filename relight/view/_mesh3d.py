"""The mesh the 3D view draws: a map set's mesh, decimated when it is large, and the per-vertex curvature its
subsurface approximation uses.

Decimation is vertex clustering (Rossignac & Borrel 1993, "Multi-resolution 3D approximations for rendering
complex scenes") on a cubic grid, made seam-safe for a UV atlas: the vertices of one grid cell are merged into
one vertex per UV chart (the connected components of the faces' vertex graph: a mesh with per-vertex UVs splits
its vertices along the seams), so no merged vertex blends two charts' UVs; every vertex of a cell, whatever its
chart, moves to the cell's one mean position, so the two sides of a seam stay joined (no cracks). Faces whose
corners fall in fewer than three clusters are dropped; faces that fold onto one another are kept (removing one of a
pair would open its edges). The cell size is the smallest (on a halving search) that
gives at most the asked number of triangles.
"""

from __future__ import annotations

import numpy as np

import stage

__all__ = ["decimate_mesh", "vertex_curvature"]


def _charts(n_vertices: int, faces: np.ndarray) -> np.ndarray:
    """int [N] chart label of each vertex: connected components of the graph of the faces' edges."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    a = np.concatenate([faces[:, 0], faces[:, 1], faces[:, 2]])
    b = np.concatenate([faces[:, 1], faces[:, 2], faces[:, 0]])
    graph = coo_matrix((np.ones(len(a), np.int8), (a, b)), shape=(n_vertices, n_vertices))
    return connected_components(graph, directed=False)[1].astype(np.int64)


def _cluster(mesh: stage.Mesh, charts: np.ndarray, cell: float) -> stage.Mesh:
    """``mesh`` with its vertices merged per (grid cell of side ``cell`` mm, chart)."""
    v = np.asarray(mesh.vertices, np.float64)
    ijk = np.floor((v - v.min(axis=0)) / cell).astype(np.int64)
    _, cell_id = np.unique(ijk, axis=0, return_inverse=True)
    cell_id = cell_id.reshape(-1)
    _, cluster = np.unique(np.stack([cell_id, charts], axis=1), axis=0, return_inverse=True)
    cluster = cluster.reshape(-1)
    n_cells, n_clusters = int(cell_id.max()) + 1, int(cluster.max()) + 1

    def mean(values, group, n):
        sums = np.stack([np.bincount(group, values[:, c], n) for c in range(values.shape[1])], axis=1)
        return sums / np.maximum(np.bincount(group, minlength=n), 1)[:, None]

    cell_of_cluster = np.zeros(n_clusters, np.int64)
    cell_of_cluster[cluster] = cell_id
    position = mean(v, cell_id, n_cells)[cell_of_cluster]  # one position per cell: the seams stay closed
    normal = mean(np.asarray(mesh.normals, np.float64), cluster, n_clusters)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    uv = mean(np.asarray(mesh.uv, np.float64), cluster, n_clusters)
    f = cluster[np.asarray(mesh.faces)]
    keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])
    f = f[keep]
    used, f = np.unique(f, return_inverse=True)
    return stage.Mesh(position[used], f.reshape(-1, 3).astype(np.int64), normal[used], uv[used],
                      f"{mesh.name} (decimated)")


def decimate_mesh(mesh: stage.Mesh, max_triangles: int) -> stage.Mesh:
    """``mesh`` reduced to at most ``max_triangles`` triangles by seam-safe vertex clustering (module
    docstring); returned unchanged when it already has that few.

    Args:
        mesh: a mesh with UVs (positions in mm).
        max_triangles: the most triangles kept (>= 1).

    Returns:
        The decimated ``stage.Mesh`` (positions, normals and UVs the means of each cluster's vertices).

    References:
        Rossignac & Borrel 1993, "Multi-resolution 3D approximations for rendering complex scenes".
    """
    if not isinstance(max_triangles, (int, np.integer)) or isinstance(max_triangles, bool) or max_triangles < 1:
        raise ValueError(f"max_triangles must be an integer >= 1, got {max_triangles!r}")
    if mesh.uv is None:
        raise ValueError(f"mesh '{mesh.name}' has no UVs")
    if len(mesh.faces) <= max_triangles:
        return mesh
    charts = _charts(len(mesh.vertices), np.asarray(mesh.faces, np.int64))
    extent = float(np.max(np.ptp(np.asarray(mesh.vertices, np.float64), axis=0)))
    # Halve the cell from the whole extent while the result still fits; then bisect between the last two.
    hi = extent
    best = _cluster(mesh, charts, hi)
    while hi > extent * 1e-6:
        trial = _cluster(mesh, charts, hi / 2)
        if len(trial.faces) > max_triangles:
            break
        hi, best = hi / 2, trial
    lo = hi / 2
    for _ in range(12):
        mid = 0.5 * (lo + hi)
        trial = _cluster(mesh, charts, mid)
        if len(trial.faces) <= max_triangles:
            hi, best = mid, trial
        else:
            lo = mid
    return best


def vertex_curvature(mesh: stage.Mesh) -> np.ndarray:
    """float [N] mean absolute normal curvature at each vertex (1/mm): over the vertex's edges e = p_j - p_i,
    the mean of |(n_j - n_i) . e| / |e|^2 (the finite-difference normal curvature along the edge, Meyer et al.
    2003, "Discrete differential-geometry operators for triangulated 2-manifolds", eq. 5 in its edge form);
    0 at a vertex without edges of positive length."""
    v = np.asarray(mesh.vertices, np.float64)
    n = np.asarray(mesh.normals, np.float64)
    f = np.asarray(mesh.faces, np.int64)
    i = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    j = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    e = v[j] - v[i]
    len2 = np.sum(e * e, axis=1)
    ok = len2 > 1e-12
    k = np.where(ok, np.abs(np.sum((n[j] - n[i]) * e, axis=1)) / np.where(ok, len2, 1.0), 0.0)
    ends = np.concatenate([i[ok], j[ok]])
    total = np.bincount(ends, np.concatenate([k[ok], k[ok]]), len(v))
    count = np.bincount(ends, minlength=len(v))
    return total / np.maximum(count, 1)

"""Small test meshes with UVs, built in code."""

import numpy as np

import stage


def plane(size=200.0, n=40, y=0.0):
    """A square in the xz-plane at height y, facing +y, with a UV grid."""
    g = np.linspace(-size / 2, size / 2, n + 1)
    x, z = np.meshgrid(g, g, indexing="xy")
    verts = np.stack([x.ravel(), np.full(x.size, y), z.ravel()], 1)
    uv = np.stack([(x.ravel() + size / 2) / size, 1 - (z.ravel() + size / 2) / size], 1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)])
    normals = np.tile([0.0, 1.0, 0.0], (len(verts), 1))
    return stage.Mesh(verts, faces, normals, uv, "plane")


def uv_sphere(radius=50.0, n_lat=48, n_lon=96, center=(0.0, 0.0, 0.0), with_uv=True):
    """A latitude-longitude sphere with an equirectangular UV map (a seam at u = 0)."""
    th = np.linspace(0, np.pi, n_lat + 1)
    ph = np.linspace(0, 2 * np.pi, n_lon + 1)
    T, Pp = np.meshgrid(th, ph, indexing="ij")
    n = np.stack([np.sin(T) * np.cos(Pp), np.cos(T), np.sin(T) * np.sin(Pp)], -1).reshape(-1, 3)
    verts = radius * n + np.asarray(center)
    uv = np.stack([Pp.ravel() / (2 * np.pi), 1 - T.ravel() / np.pi], 1)
    idx = np.arange((n_lat + 1) * (n_lon + 1)).reshape(n_lat + 1, n_lon + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)])
    # Drop the zero-area triangles at the poles.
    v = verts[faces]
    keep = np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1) > 1e-9
    return stage.Mesh(verts, faces[keep], n, uv if with_uv else None, "sphere")


def merge(*meshes, uv_of=0):
    """Concatenate meshes; only mesh ``uv_of`` keeps its UVs (others get degenerate UVs)."""
    verts, faces, normals, uvs, off = [], [], [], [], 0
    for i, m in enumerate(meshes):
        verts.append(m.vertices)
        faces.append(m.faces + off)
        normals.append(m.normals)
        uvs.append(m.uv if i == uv_of else np.full((len(m.vertices), 2), -1.0))
        off += len(m.vertices)
    return stage.Mesh(np.concatenate(verts), np.concatenate(faces), np.concatenate(normals), np.concatenate(uvs),
                      "merged")

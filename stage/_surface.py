"""Surface samples on a texel grid, rasterised from a mesh's UV atlas."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from brdf import frame_from_normal_tangent

from ._forward import _traced, to_local
from ._mesh import Mesh


class Surface(eqx.Module):
    """P surface samples: world position [P, 3] (mm), shading frame normal /
    tangent / bitangent [P, 3] (right-handed, t x b = n), uv [P, 2], area [P]
    (mm^2), and where each sample lives on the ``resolution`` texel grid
    (``texel_index`` [P] into the row-major grid, row 0 at v = 1), the mesh
    ``face`` [P] each sample lies on and its ``barycentric`` [P, 3] coordinates
    in that face. Image-space samples (``image_samples``) use the same type with
    the image as the grid (``texel_index`` = row * width + column)."""

    position: Float[Array, "sample 3"]
    normal: Float[Array, "sample 3"]
    tangent: Float[Array, "sample 3"]
    bitangent: Float[Array, "sample 3"]
    uv: Float[Array, "sample 2"]
    area: Float[Array, " sample"]
    texel_index: Int[Array, " sample"]
    face: Int[Array, " sample"]
    resolution: tuple[int, int] = eqx.field(static=True)
    barycentric: Float[Array, "sample 3"] | None = None

    @property
    def num_samples(self) -> int:
        return self.position.shape[0]

    def to_local(self, w: Float[ArrayLike, "*batch sample 3"]) -> Float[Array, "*batch sample 3"]:
        """World directions to the shading frame (z = normal): ``stage.to_local``
        with this surface's (tangent, bitangent, normal)."""
        return to_local(w, self.tangent, self.bitangent, self.normal)

    def to_texture(self, values, fill=0.0) -> np.ndarray:
        """Scatter per-sample values [P, ...] to a texture [H, W, ...] (``fill`` elsewhere)."""
        values = np.asarray(values)
        h, w = self.resolution
        out = np.full((h * w,) + values.shape[1:], fill, dtype=values.dtype)
        out[np.asarray(self.texel_index)] = values
        return out.reshape((h, w) + values.shape[1:])

    def subset(self, index) -> Surface:
        """The samples ``index`` (an index array or boolean mask over P, concrete).
        Works on traced fields too (under jax.grad / jit), as a gather; concrete fields are taken on the host
        (:meth:`take`), so no gather is compiled for each index length."""
        if not _traced(self):
            return self.take(index)
        index = np.asarray(index)
        if index.dtype == bool:
            index = np.flatnonzero(index)
        take = lambda a: jnp.asarray(a)[index]  # noqa: E731
        return Surface(position=take(self.position), normal=take(self.normal), tangent=take(self.tangent),
                       bitangent=take(self.bitangent), uv=take(self.uv), area=take(self.area),
                       texel_index=take(self.texel_index), face=take(self.face), resolution=self.resolution,
                       barycentric=None if self.barycentric is None else take(self.barycentric))

    def take(self, index) -> Surface:
        """The samples ``index`` taken on the host: NumPy rows of every field, then device arrays.

        The same samples as :meth:`subset`, without a gather program compiled for each index length
        (for concrete fields only; under ``jax.jit`` / ``jax.grad`` use :meth:`subset`).

        Args:
            index: int [N] sample indices (or a boolean mask over P), concrete.

        Returns:
            A ``Surface`` of the N samples, on the same texel grid.
        """
        index = np.asarray(index)
        # device_put, not jnp.asarray: the latter compiles (and JAX keeps) a program for each new shape.
        return jax.tree_util.tree_map(lambda a: jax.device_put(np.asarray(a)[index]), self)


# Candidate texels (the texels of the triangles' UV bounding boxes) generated and
# tested per batch: ~25 float64 / int64 arrays over each, ~200 B a candidate, so
# ~50 MiB a batch at 2^18 at most, however large the grid.
_CANDIDATE_BATCH = 1 << 18
# Samples interpolated per batch: the float64 temporaries of the interpolation
# and the frame (~300 B a sample) for 2^16 samples at a time, ~20 MiB.
_SAMPLE_BATCH = 1 << 16


def _texel_hits(tc, F, h: int, w: int, batch: int):
    """The (face, texel index, l1, l2) of every texel centre inside a UV
    triangle, in face order then row-major within each face's bounding box
    (the order the first-triangle-wins rule reads). The bounding-box candidates
    are generated and tested ``batch`` at a time (a face's box may be split
    between batches), so the temporaries are one batch's; only the hits are
    kept (int64, int64, float64, float64)."""
    t0, t1, t2 = tc[F[:, 0]], tc[F[:, 1]], tc[F[:, 2]]
    lo = np.floor(np.minimum(np.minimum(t0, t1), t2) - 0.5).astype(np.int64) + 1
    hi = np.floor(np.maximum(np.maximum(t0, t1), t2) - 0.5).astype(np.int64)
    lo = np.clip(lo, 0, [w - 1, h - 1])
    hi = np.clip(hi, -1, [w - 1, h - 1])
    nx = np.maximum(hi[:, 0] - lo[:, 0] + 1, 0)
    ny = np.maximum(hi[:, 1] - lo[:, 1] + 1, 0)
    counts = nx * ny
    end = np.cumsum(counts)  # candidate j belongs to the face with end[f - 1] <= j < end[f]
    total = int(end[-1]) if len(end) else 0
    parts = []
    for s in range(0, total, batch):
        j = np.arange(s, min(s + batch, total), dtype=np.int64)
        tri = np.searchsorted(end, j, side="right")
        k = j - (end[tri] - counts[tri])
        px = lo[tri, 0] + k % nx[tri]
        py = lo[tri, 1] + k // nx[tri]
        c = np.stack([px + 0.5, py + 0.5], axis=1)
        a = t0[tri]
        v0, v1, v2 = t1[tri] - a, t2[tri] - a, c - a
        den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
        ok = np.abs(den) > 1e-14
        den = np.where(ok, den, 1.0)
        l1 = (v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / den
        l2 = (v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / den
        l0 = 1 - l1 - l2
        eps = -1e-9
        inside = ok & (l0 >= eps) & (l1 >= eps) & (l2 >= eps)
        parts.append((tri[inside], (py * w + px)[inside], l1[inside], l2[inside]))
    if not parts:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros(0)
    # One field at a time, each batch's part dropped once copied: the hits are never held twice over.
    out = []
    for i in range(4):
        out.append(np.concatenate([q[i] for q in parts]))
        parts = [(*q[:i], None, *q[i + 1:]) for q in parts]
    return tuple(out)


def texel_samples(mesh: Mesh, resolution: int | tuple[int, int] = 256) -> Surface:
    """Rasterise a mesh's UV atlas: one sample per texel whose centre falls inside a UV triangle.

    The first triangle wins where charts overlap. Position and normal are interpolated barycentrically; the tangent
    is dP/du of the triangle (Gram-Schmidt against the normal); the area is the triangle's world-to-UV area ratio
    times the texel's UV area. Memory: the triangles' bounding-box texels are tested ``_CANDIDATE_BATCH`` (2^18) at
    a time and the samples interpolated ``_SAMPLE_BATCH`` (2^16) at a time, so beyond the result (~70 B a sample)
    and ~40 B per texel hit (kept to resolve overlaps) the temporaries are bounded by the batch sizes, not by the
    grid; the result does not depend on them.

    Args:
        mesh: a mesh with UVs.
        resolution: the texel grid, N (N x N) or (H, W).

    Returns:
        The ``Surface``.
    """
    if mesh.uv is None:
        raise ValueError(f"mesh '{mesh.name}' has no UV coordinates; texel-space sampling needs them")
    h, w = (resolution, resolution) if np.isscalar(resolution) else tuple(resolution)
    if h <= 0 or w <= 0:
        raise ValueError(f"texel resolution must be positive, got {h}x{w}")
    V, F, UV = mesh.vertices, mesh.faces, mesh.uv
    # Texel coordinates (x along u, y along 1 - v so that row 0 is the top of the texture).
    tc = np.stack([UV[:, 0] * w, (1.0 - UV[:, 1]) * h], axis=1)
    tri, idx, l1, l2 = _texel_hits(tc, F, h, w, _CANDIDATE_BATCH)
    idx_unique, first = np.unique(idx, return_index=True)
    del idx
    tri, l1, l2 = tri[first], l1[first], l2[first]
    if len(idx_unique) == 0:
        raise ValueError(f"mesh '{mesh.name}': no texel centre falls inside any UV triangle at {h}x{w}")
    # Per-triangle dP/du and the world/UV area ratio.
    e1, e2 = V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]
    d1, d2 = UV[F[:, 1]] - UV[F[:, 0]], UV[F[:, 2]] - UV[F[:, 0]]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    safe_det = np.where(np.abs(det) > 1e-20, det, 1.0)
    dpdu = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) / safe_det[:, None]
    world_area = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
    uv_area = 0.5 * np.abs(det)
    ratio = np.where(uv_area > 1e-20, world_area / np.where(uv_area > 1e-20, uv_area, 1.0), 0.0)
    P = len(idx_unique)
    out = {k: np.empty((P, n), np.float32) for k, n in
           (("position", 3), ("normal", 3), ("tangent", 3), ("bitangent", 3), ("uv", 2), ("barycentric", 3))}
    area = np.empty(P, np.float32)
    # Row by row arithmetic, so interpolating in batches gives the same bits as all at once.
    for s in range(0, P, _SAMPLE_BATCH):
        r = slice(s, min(s + _SAMPLE_BATCH, P))
        fr, b1, b2 = tri[r], l1[r], l2[r]
        f = F[fr]
        lam = np.stack([1 - b1 - b2, b1, b2], axis=1)[:, :, None]
        nrm = np.sum(mesh.normals[f] * lam, axis=1)
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
        t, b = frame_from_normal_tangent(nrm, dpdu[fr])
        out["position"][r] = np.sum(V[f] * lam, axis=1)
        out["normal"][r], out["tangent"][r], out["bitangent"][r] = nrm, t, b
        out["uv"][r] = np.sum(UV[f] * lam, axis=1)
        out["barycentric"][r] = lam[:, :, 0]
        area[r] = ratio[fr] / (h * w)
    del l1, l2
    texel_index, face = idx_unique.astype(np.int32), tri.astype(np.int32)
    del idx_unique, tri
    # Each field handed to JAX and its NumPy copy dropped in turn, so both copies of the whole set never coexist;
    # by device_put: jnp.asarray compiles a program per new shape and held twice the array's bytes (measured).
    fields = {k: jax.device_put(out.pop(k)) for k in list(out)}
    return Surface(**fields, area=jax.device_put(area), texel_index=jax.device_put(texel_index),
                   face=jax.device_put(face), resolution=(int(h), int(w)))

"""Surface samples on a texel grid, rasterised from a mesh's UV atlas."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from brdf import frame_from_normal_tangent

from ._forward import to_local
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
        Works on traced fields too (under jax.grad / jit), as a gather."""
        index = np.asarray(index)
        if index.dtype == bool:
            index = np.flatnonzero(index)
        take = lambda a: jnp.asarray(a)[index]  # noqa: E731
        return Surface(position=take(self.position), normal=take(self.normal), tangent=take(self.tangent),
                       bitangent=take(self.bitangent), uv=take(self.uv), area=take(self.area),
                       texel_index=take(self.texel_index), face=take(self.face), resolution=self.resolution,
                       barycentric=None if self.barycentric is None else take(self.barycentric))


def texel_samples(mesh: Mesh, resolution: int | tuple[int, int] = 256) -> Surface:
    """Rasterise the UV atlas: one sample per texel whose centre falls inside a
    UV triangle (first triangle wins where charts overlap).

    Position and normal are interpolated barycentrically; the tangent is dP/du
    of the triangle (Gram-Schmidt against the normal); the area is the
    triangle's world-to-UV area ratio times the texel's UV area.
    """
    if mesh.uv is None:
        raise ValueError(f"mesh '{mesh.name}' has no UV coordinates; texel-space sampling needs them")
    h, w = (resolution, resolution) if np.isscalar(resolution) else tuple(resolution)
    if h <= 0 or w <= 0:
        raise ValueError(f"texel resolution must be positive, got {h}x{w}")
    V, F, UV = mesh.vertices, mesh.faces, mesh.uv
    # Texel coordinates (x along u, y along 1 - v so that row 0 is the top of the texture).
    tc = np.stack([UV[:, 0] * w, (1.0 - UV[:, 1]) * h], axis=1)
    t0, t1, t2 = tc[F[:, 0]], tc[F[:, 1]], tc[F[:, 2]]
    lo = np.floor(np.minimum(np.minimum(t0, t1), t2) - 0.5).astype(np.int64) + 1
    hi = np.floor(np.maximum(np.maximum(t0, t1), t2) - 0.5).astype(np.int64)
    lo = np.clip(lo, 0, [w - 1, h - 1])
    hi = np.clip(hi, -1, [w - 1, h - 1])
    nx = np.maximum(hi[:, 0] - lo[:, 0] + 1, 0)
    ny = np.maximum(hi[:, 1] - lo[:, 1] + 1, 0)
    counts = nx * ny
    tri = np.repeat(np.arange(len(F)), counts)
    start = np.repeat(np.cumsum(counts) - counts, counts)
    k = np.arange(counts.sum()) - start
    px = lo[tri, 0] + k % nx[tri]
    py = lo[tri, 1] + k // nx[tri]
    c = np.stack([px + 0.5, py + 0.5], axis=1)
    a, b_, c_ = t0[tri], t1[tri], t2[tri]
    v0, v1, v2 = b_ - a, c_ - a, c - a
    den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
    ok = np.abs(den) > 1e-14
    den = np.where(ok, den, 1.0)
    l1 = (v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / den
    l2 = (v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / den
    l0 = 1 - l1 - l2
    eps = -1e-9
    inside = ok & (l0 >= eps) & (l1 >= eps) & (l2 >= eps)
    tri, px, py, l0, l1, l2 = tri[inside], px[inside], py[inside], l0[inside], l1[inside], l2[inside]
    idx = py * w + px
    idx_unique, first = np.unique(idx, return_index=True)
    tri, l0, l1, l2 = tri[first], l0[first], l1[first], l2[first]
    if len(idx_unique) == 0:
        raise ValueError(f"mesh '{mesh.name}': no texel centre falls inside any UV triangle at {h}x{w}")
    f = F[tri]
    lam = np.stack([l0, l1, l2], axis=1)[:, :, None]
    pos = np.sum(V[f] * lam, axis=1)
    nrm = np.sum(mesh.normals[f] * lam, axis=1)
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
    uv = np.sum(UV[f] * lam, axis=1)
    # Per-triangle dP/du and the world/UV area ratio.
    e1, e2 = V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]
    d1, d2 = UV[F[:, 1]] - UV[F[:, 0]], UV[F[:, 2]] - UV[F[:, 0]]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    safe_det = np.where(np.abs(det) > 1e-20, det, 1.0)
    dpdu = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) / safe_det[:, None]
    world_area = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
    uv_area = 0.5 * np.abs(det)
    ratio = np.where(uv_area > 1e-20, world_area / np.where(uv_area > 1e-20, uv_area, 1.0), 0.0)
    t, b = frame_from_normal_tangent(nrm, dpdu[tri])
    area = ratio[tri] / (h * w)
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    return Surface(position=f32(pos), normal=f32(nrm), tangent=f32(t), bitangent=f32(b), uv=f32(uv),
                   area=f32(area), texel_index=jnp.asarray(idx_unique, jnp.int32),
                   face=jnp.asarray(tri, jnp.int32), resolution=(int(h), int(w)),
                   barycentric=f32(lam[:, :, 0]))

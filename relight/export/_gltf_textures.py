"""The map -> glTF texture conversions of :func:`relight.export.write_gltf`, and their inverses.

Everything here is NumPy on the texel grid: the mesh's per-vertex tangent frame (what the glTF's
``TANGENT`` attribute holds), the frame a glTF renderer interpolates at each texel, and each fitted map
encoded as the 8-bit (or 16-bit) PNG pixels glTF's metallic-roughness material, ``KHR_materials_specular``
and ``KHR_materials_anisotropy`` read, with :func:`decode_material` the exact inverse of the encoding (what a
glTF renderer sees, in relight's own terms). The mapping and its approximations: docs/export.md.
"""

from __future__ import annotations

import dataclasses
import io

import numpy as np

from ..image import srgb_decode, srgb_encode
from ..materials import GGX, GGX_ANISO, LAMBERT, SUBSURFACE

__all__ = ["GltfTextures", "decode_material", "encode_material", "from_tangent_space", "png_bytes", "png_pixels",
           "texel_frames", "to_tangent_space", "vertex_tangents"]

# glTF's dielectric F0 at its default ior = 1.5: ((1.5 - 1) / (1.5 + 1))^2 (KHR_materials_specular's 0.04).
GLTF_F0 = 0.04
# A tangent-space normal's z is kept at least this (a fitted normal more than ~89.9 degrees from the mesh's
# interpolated one cannot be a normal map's texel; such texels are counted in the export's report).
_MIN_Z = 1e-3
# Triangles whose UV area (in uv^2) is below this give no tangent (their dP/du is undefined).
_MIN_UV_DET = 1e-14


def _unit(v: np.ndarray, fallback=None) -> np.ndarray:
    """Rows of ``v`` normalised; rows of length ~0 become ``fallback`` (rows, or +z)."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    ok = n > 1e-12
    fb = np.broadcast_to(np.asarray([0.0, 0.0, 1.0] if fallback is None else fallback, v.dtype), v.shape)
    return np.where(ok, v / np.where(ok, n, 1.0), fb)


def _any_perpendicular(n: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to each unit row of ``n`` (Duff et al. 2017's branchless basis)."""
    s = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (s + n[:, 2])
    c = n[:, 0] * n[:, 1] * a
    return np.stack([1.0 + s * n[:, 0] ** 2 * a, s * c, -s * n[:, 0]], -1)


def vertex_tangents(vertices, faces, normals, uv) -> np.ndarray:
    """Per-vertex tangents (glTF's ``TANGENT``: unit xyz, w = +-1) of a mesh with UVs.

    The MikkTSpace construction without its vertex splitting (glTF's vertices are the mesh's, kept): each
    triangle's dP/du and dP/dv (v up the image, the mesh's own UVs, whose v glTF's texture coordinate 1 - v
    flips) are made orthogonal to each of its vertices' normals, normalised, and summed with the corner's
    angle as the weight; the sum of tangents is made orthogonal to the vertex normal (Gram-Schmidt) and w is
    the sign of (N x T) . (summed dP/dv), so that glTF's bitangent w (N x T) points up the image, which is
    where a normal texture's +Y (green) points. Vertices on no triangle with a UV area get any tangent
    perpendicular to their normal, w = 1.

    Args:
        vertices: [V, 3] positions (any length unit).
        faces: [F, 3] vertex indices.
        normals: [V, 3] unit vertex normals.
        uv: [V, 2] texture coordinates, v up the image (the project's meshes' convention).

    Returns:
        float64 [V, 4]: xyz unit and orthogonal to the normal, w in {-1, +1}.

    References:
        Mikkelsen 2008, "Simulation of wrinkled surfaces revisited" (MikkTSpace); the glTF 2.0 specification,
        3.7.2.1 (TANGENT) and 3.9.3 (normalTexture: +X right, +Y up).
    """
    P = np.asarray(vertices, np.float64)
    F = np.asarray(faces, np.int64)
    N = _unit(np.asarray(normals, np.float64))
    UV = np.asarray(uv, np.float64)
    e1, e2 = P[F[:, 1]] - P[F[:, 0]], P[F[:, 2]] - P[F[:, 0]]
    d1, d2 = UV[F[:, 1]] - UV[F[:, 0]], UV[F[:, 2]] - UV[F[:, 0]]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    ok = np.abs(det) > _MIN_UV_DET
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)[:, None]
    t_face = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) * inv
    b_face = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) * inv
    t_sum = np.zeros_like(P)
    b_sum = np.zeros_like(P)
    for k in range(3):
        v = F[:, k]
        a = _unit(P[F[:, (k + 1) % 3]] - P[v])
        b = _unit(P[F[:, (k + 2) % 3]] - P[v])
        angle = np.arccos(np.clip(np.sum(a * b, -1), -1.0, 1.0))[:, None] * ok[:, None]
        n = N[v]
        t = t_face - np.sum(t_face * n, -1, keepdims=True) * n
        bb = b_face - np.sum(b_face * n, -1, keepdims=True) * n
        tl, bl = np.linalg.norm(t, axis=-1, keepdims=True), np.linalg.norm(bb, axis=-1, keepdims=True)
        np.add.at(t_sum, v, angle * t / np.maximum(tl, 1e-30))
        np.add.at(b_sum, v, angle * bb / np.maximum(bl, 1e-30))
    t = t_sum - np.sum(t_sum * N, -1, keepdims=True) * N
    t = _unit(t, _any_perpendicular(N))
    t = _unit(t - np.sum(t * N, -1, keepdims=True) * N)  # exactly orthogonal after the fallback too
    w = np.where(np.sum(np.cross(N, t) * b_sum, -1) < 0, -1.0, 1.0)
    return np.concatenate([t, w[:, None]], -1)


def texel_frames(normals, tangents, faces, face, barycentric) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The (T, B, N) a glTF renderer interpolates at each texel sample, each normalised.

    Per vertex: N the vertex normal, T the tangent's xyz, B = w (N x T) (glTF 2.0 3.7.2.1); each is
    interpolated barycentrically over the sample's triangle and normalised (the Khronos sample viewer's
    fragment stage; no re-orthogonalisation).

    Args:
        normals: [V, 3] vertex normals; tangents: [V, 4] (:func:`vertex_tangents`).
        faces: [F, 3]; face: [P] each sample's triangle; barycentric: [P, 3] its weights (``stage.Surface``'s).

    Returns:
        (T, B, N), float64 [P, 3] each.
    """
    Nv = np.asarray(normals, np.float64)
    Tv = np.asarray(tangents, np.float64)
    Bv = np.cross(Nv, Tv[:, :3]) * Tv[:, 3:4]
    f = np.asarray(faces, np.int64)[np.asarray(face, np.int64)]
    lam = np.asarray(barycentric, np.float64)[:, :, None]
    lerp = lambda a: _unit(np.sum(a[f] * lam, axis=1))  # noqa: E731
    return lerp(Tv[:, :3]), lerp(Bv), lerp(Nv)


def to_tangent_space(d, T, B, N) -> np.ndarray:
    """Unit coordinates c with T c_x + B c_y + N c_z parallel to the world direction ``d`` ([P, 3] each):
    what a normal texture must hold for a renderer that decodes n = normalize(T x + B y + N z)."""
    M = np.stack([T, B, N], axis=-1)  # columns T, B, N
    # A frame that spans no volume (a triangle across a UV mirror seam, whose vertices' w differ, can
    # interpolate B to ~0 or onto T) is replaced by the orthonormal (T', N x T', N) there: no solve fails.
    bad = np.abs(np.linalg.det(M)) < 1e-6
    if bad.any():
        t = _unit(T[bad] - np.sum(T[bad] * N[bad], -1, keepdims=True) * N[bad], _any_perpendicular(N[bad]))
        M[bad] = np.stack([t, np.cross(N[bad], t), N[bad]], axis=-1)
    return _unit(np.linalg.solve(M, np.asarray(d, np.float64)[..., None])[..., 0])


def from_tangent_space(c, T, B, N) -> np.ndarray:
    """normalize(T c_x + B c_y + N c_z), the inverse of :func:`to_tangent_space` ([P, 3] each)."""
    c = np.asarray(c, np.float64)
    return _unit(T * c[:, 0:1] + B * c[:, 1:2] + N * c[:, 2:3])


def _u8(x) -> np.ndarray:
    return np.clip(np.rint(255.0 * np.asarray(x, np.float64)), 0, 255).astype(np.uint8)


def _srgb8(linear) -> np.ndarray:
    return _u8(np.asarray(srgb_encode(np.clip(np.asarray(linear, np.float64), 0.0, 1.0))))


def _unsrgb8(code) -> np.ndarray:
    return np.asarray(srgb_decode(np.asarray(code, np.float64) / 255.0), np.float64)


@dataclasses.dataclass(frozen=True)
class GltfTextures:
    """The per-sample texel values of a glTF export (each [P, C], uint8 unless said) and the factors they go with.

    base [P, 3] sRGB base colour; metal_rough [P, 3] (R 255 unused, G roughness, B metallic 0); specular
    [P, 4] (RGB sRGB specular colour, A specular strength); normal [P, 3] (0.5 c + 0.5); anisotropy [P, 3]
    (RG direction 0.5 d + 0.5, B strength) or None when no texel is anisotropic; mfp uint16 [P, 3] or None
    (no subsurface texel); rung [P] (the ladder index); coverage [P] (255 seen, 0 not).
    ``specular_color_factor``: KHR_materials_specular's factor (F0 = 0.04 factor colour), ``mfp_scale_mm``:
    the mean free path of code 65535; ``clamped``: counts of texels whose value glTF cannot hold."""

    base: np.ndarray
    metal_rough: np.ndarray
    specular: np.ndarray
    normal: np.ndarray
    anisotropy: np.ndarray | None
    mfp: np.ndarray | None
    rung: np.ndarray
    coverage: np.ndarray
    specular_color_factor: float
    mfp_scale_mm: float
    clamped: dict


def encode_material(rho_d, rho_s, alpha, normal, tangent, mfp, model, seen, frames,
                    f0_max: float | None = None) -> GltfTextures:
    """The glTF texel values of per-sample maps (relight's model, ``relight.MaterialMaps``' fields as NumPy).

    Mapping (docs/export.md): roughness = sqrt(min(alpha_x, alpha_y)) (glTF's alpha = roughness^2); where the
    two alphas differ, KHR_materials_anisotropy's strength s = sqrt((alpha_max - alpha_min) / (1 - alpha_min))
    (its alpha_t = mix(alpha_min, 1, s^2) = alpha_max) along the fitted axis of alpha_max; F0 through
    KHR_materials_specular with specular strength 1 (F90 = 1: Schlick's curve) and 0 on Lambert texels (no
    specular lobe), specular colour F0 / F0_max (sRGB) with factor F0_max / 0.04; base colour
    rho_d / (1 - F0) (glTF weights the diffuse term by 1 - F, which this undoes at normal incidence), clamped
    to 1; the shading normal in the interpolated vertex frame (:func:`to_tangent_space`).

    Args:
        rho_d [P, 3], rho_s [P] or [P, 1], alpha [P, 2], normal [P, 3] and tangent [P, 3] (world, the fitted
            frame), mfp [P, 3] (mm), model [P] (ladder rungs), seen [P] bool: the maps at the texel samples.
        frames: (T, B, N) at the samples (:func:`texel_frames`).
        f0_max: the F0 of specular colour 1 (None: the largest F0 of a specular texel, so none is clamped);
            a larger F0 is clamped to it and counted (``clamped["f0"]``). The colour is 8-bit sRGB of F0 / f0_max,
            so a smaller f0_max gives the typical F0 finer steps (2.4 / (255 (e + 0.055)) relative at code e / 255).

    Returns:
        A :class:`GltfTextures`.
    """
    T, B, N = frames
    model = np.asarray(model, np.int64).reshape(-1)
    rho_d = np.asarray(rho_d, np.float64)
    f0 = np.clip(np.asarray(rho_s, np.float64).reshape(-1), 0.0, 1.0)
    alpha = np.asarray(alpha, np.float64).copy()
    alpha[:, 1] = np.where(model >= GGX_ANISO, alpha[:, 1], alpha[:, 0])
    spec_on = model != LAMBERT
    clamped = {"f0": 0}
    if f0_max is None:
        f0_max = float(f0[spec_on].max()) if spec_on.any() else 0.0
    else:
        clamped["f0"] = int(np.sum(spec_on & (f0 > f0_max)))
        f0 = np.minimum(f0, f0_max)
    colour = _srgb8(np.repeat((f0 / f0_max if f0_max > 0 else f0)[:, None], 3, -1))
    strength = np.where(spec_on & (f0_max > 0), 255, 0).astype(np.uint8)
    f0_q = f0_max * _unsrgb8(colour[:, 0]) * (strength / 255.0)
    base_lin = rho_d / (1.0 - np.minimum(f0_q, 1.0 - 1e-6))[:, None]
    clamped["base_color"] = int(np.sum(np.any(base_lin > 1.0 + 1e-6, -1)))
    a_min, a_max = alpha.min(1), alpha.max(1)
    rough = _u8(np.sqrt(np.clip(a_min, 0.0, 1.0)))
    metal_rough = np.stack([np.full_like(rough, 255), rough, np.zeros_like(rough)], -1)
    n_fit = _unit(np.asarray(normal, np.float64))
    c = to_tangent_space(n_fit, T, B, N)
    low = c[:, 2] < _MIN_Z
    clamped["normal"] = int(low.sum())
    c[:, 2] = np.maximum(c[:, 2], _MIN_Z)
    c = _unit(c)
    s = np.sqrt(np.clip((a_max - a_min) / np.maximum(1.0 - a_min, 1e-12), 0.0, 1.0))
    s_code = _u8(s)
    anisotropy = None
    if np.any(s_code > 0):
        t_fit = np.asarray(tangent, np.float64)
        t_fit = _unit(t_fit - np.sum(t_fit * n_fit, -1, keepdims=True) * n_fit)
        axis = np.where((alpha[:, 0] >= alpha[:, 1])[:, None], t_fit, np.cross(n_fit, t_fit))
        d = to_tangent_space(axis, T, B, N)[:, :2]
        d = np.where(np.linalg.norm(d, axis=-1, keepdims=True) > 1e-9, d, [1.0, 0.0])
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        anisotropy = np.concatenate([_u8(0.5 * d + 0.5), s_code[:, None]], -1)
    mfp_codes, mfp_scale = None, 0.0
    sss = model == SUBSURFACE
    if sss.any():
        m = np.clip(np.asarray(mfp, np.float64), 0.0, None)
        mfp_scale = float(m[sss].max()) or 1.0
        mfp_codes = np.clip(np.rint(65535.0 * m / mfp_scale), 0, 65535).astype(np.uint16)
    return GltfTextures(
        base=_srgb8(base_lin), metal_rough=metal_rough, specular=np.concatenate([colour, strength[:, None]], -1),
        normal=_u8(0.5 * c + 0.5), anisotropy=anisotropy, mfp=mfp_codes, rung=model.astype(np.uint8),
        coverage=np.where(np.asarray(seen, bool), 255, 0).astype(np.uint8),
        specular_color_factor=f0_max / GLTF_F0, mfp_scale_mm=mfp_scale, clamped=clamped)


def decode_material(textures: GltfTextures, frames, *, extras: bool = False) -> dict:
    """What a glTF renderer reads from :func:`encode_material`'s texels, as relight's per-sample maps.

    The inverse of the mapping (docs/export.md): F0 = min(0.04 factor colour, 1) strength, rho_d =
    base (1 - F0), alpha_min = roughness^2, alpha_max = mix(alpha_min, 1, s^2) along the decoded anisotropy
    axis, the normal n = normalize(T x + B y + N z). ``extras=False``: the rungs glTF draws (lambert where the
    specular strength is 0, ggx_aniso where s > 0, else ggx; mfp 0); True: the rungs and the mean free path
    the file's relight extras record.

    Returns:
        dict of float64 rho_d [P, 3], rho_s [P, 1], alpha [P, 2], normal [P, 3], tangent [P, 3], mfp [P, 3]
        and int32 model [P] (``relight.material_maps``' arguments).
    """
    T, B, N = frames
    strength = textures.specular[:, 3] / 255.0
    f0 = np.minimum(GLTF_F0 * textures.specular_color_factor * _unsrgb8(textures.specular[:, 0]), 1.0) * strength
    rho_d = _unsrgb8(textures.base[:, :3]) * (1.0 - f0)[:, None]
    a_min = (textures.metal_rough[:, 1] / 255.0) ** 2
    normal = from_tangent_space(textures.normal / 127.5 - 1.0, T, B, N)
    tangent = _unit(T - np.sum(T * normal, -1, keepdims=True) * normal, _any_perpendicular(normal))
    a_max = a_min
    if textures.anisotropy is not None:
        d = textures.anisotropy[:, :2] / 127.5 - 1.0
        s = textures.anisotropy[:, 2] / 255.0
        a_max = a_min + (1.0 - a_min) * s * s
        axis = _unit(T * d[:, 0:1] + B * d[:, 1:2])
        axis = axis - np.sum(axis * normal, -1, keepdims=True) * normal
        tangent = np.where((s > 0)[:, None], _unit(axis, tangent), tangent)
    aniso = a_max > a_min
    model = np.where(strength == 0, LAMBERT, np.where(aniso, GGX_ANISO, GGX)).astype(np.int32)
    mfp = np.zeros_like(rho_d)
    if extras:
        model = textures.rung.astype(np.int32)
        if textures.mfp is not None:
            mfp = textures.mfp / 65535.0 * textures.mfp_scale_mm
    alpha = np.stack([a_max, a_min], -1)
    return {"rho_d": rho_d, "rho_s": f0[:, None], "alpha": np.maximum(alpha, 1e-8), "normal": normal,
            "tangent": tangent, "mfp": mfp, "model": model}


def fill_nearest(values: np.ndarray, texel_index, resolution) -> np.ndarray:
    """A full texture [H, W, ...] of per-sample ``values`` [P, ...] at ``texel_index`` (row-major), every other
    texel (the gutter and background between UV charts) holding its nearest sample texel's value (Euclidean
    distance on the grid): no invented value, and mip-mapping and bilinear lookups near a chart border blend
    only the chart's own values."""
    from scipy import ndimage

    h, w = resolution
    values = np.asarray(values)
    grid = np.zeros((h * w,) + values.shape[1:], values.dtype)
    grid[np.asarray(texel_index)] = values
    grid = grid.reshape((h, w) + values.shape[1:])
    have = np.zeros(h * w, bool)
    have[np.asarray(texel_index)] = True
    have = have.reshape(h, w)
    if have.all():
        return grid
    rows, cols = ndimage.distance_transform_edt(~have, return_distances=False, return_indices=True)
    return grid[rows, cols]


def png_bytes(image: np.ndarray) -> bytes:
    """A PNG file's bytes of an [H, W] or [H, W, C] (C in 1..4) uint8 or uint16 image (no gamma chunk: glTF says
    per texture slot whether its values are sRGB or linear). 8 bits through Pillow, 16 through pypng
    (Pillow has no 16-bit colour PNG)."""
    img = np.asarray(image)
    if img.ndim == 2:
        img = img[:, :, None]
    h, w, c = img.shape
    buf = io.BytesIO()
    if img.dtype == np.uint16:
        import png

        png.Writer(w, h, greyscale=c < 3, alpha=c in (2, 4), bitdepth=16).write_array(buf, img.reshape(-1))
        return buf.getvalue()
    from PIL import Image

    # The mode follows from the shape: L, LA, RGB, RGBA.
    Image.fromarray(np.ascontiguousarray(img[:, :, 0] if c == 1 else img, np.uint8)).save(buf, "PNG")
    return buf.getvalue()


def png_pixels(data: bytes) -> np.ndarray:
    """The pixels [H, W, C] (uint8 or uint16, as stored) of a PNG file's bytes (:func:`png_bytes`' inverse)."""
    import png

    w, h, rows, info = png.Reader(bytes=data).asDirect()
    dtype = np.uint16 if info["bitdepth"] > 8 else np.uint8
    arr = np.vstack([np.asarray(r, dtype)[None] for r in rows])
    return arr.reshape(h, w, info["planes"])

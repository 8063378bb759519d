"""Export a fitted map set as binary glTF 2.0 (``.glb``): the mesh with its UVs and a PBR material.

One file: a 12-byte header, a JSON chunk and a BIN chunk (glTF 2.0 section 4.4), every bufferView 4-byte
aligned. The mesh (one primitive: POSITION in metres, NORMAL, TANGENT, TEXCOORD_0 and triangle indices) keeps
the map set's mesh vertex for vertex; the material is glTF's metallic-roughness model with
``KHR_materials_specular`` (always) and ``KHR_materials_anisotropy`` (where a texel is anisotropic), its
textures PNGs at the map set's resolution. What glTF cannot express (each texel's rung, the mean free path,
the coverage, the units, the rig, the map set's own record) is under the root's ``extras.relight``.

Mapping (docs/export.md has it with the measured differences):

* base colour = rho_d / (1 - F0) (sRGB 8-bit; glTF scales its diffuse term by 1 - F(V.H), so this is exact at
  normal incidence), clamped to 1 (counted);
* roughness = sqrt(alpha) in the metallicRoughness texture's G (glTF's alpha = roughness^2), metallic 0 (B);
* F0 through ``KHR_materials_specular``: specular 1 (so F90 = 1, Schlick's curve, as relight's), specular
  colour F0 / F0_max (sRGB) times the factor F0_max / 0.04, so dielectricSpecularF0 = min(0.04 factor colour,
  1) specular = F0; Lambert texels have specular 0 (no lobe at all);
* the anisotropic rungs (ggx_aniso, subsurface): ``KHR_materials_anisotropy`` with roughness from the smaller
  alpha and strength s = sqrt((alpha_max - alpha_min) / (1 - alpha_min)), direction the fitted axis of the
  larger alpha in the tangent frame (RG) - exact, since the extension's alpha_t = mix(alpha_min, 1, s^2);
* blinn_phong: GGX of the stored alpha (the map set already holds alpha = sqrt(2 / (n + 2)) for exponent n,
  Walter et al. 2007's correspondence), F0 = the lobe's albedo rho_s: an approximation;
* subsurface: the total diffuse reflectance as base colour (a local Lambert term: the zero-mean-free-path
  limit), the mean free path in extras as a 16-bit PNG;
* the fitted normal as a tangent-space normal texture in the interpolated vertex frame that a glTF renderer
  builds from NORMAL and TANGENT (MikkTSpace-style tangents, +Y = green up the image).

Texels no camera saw carry the map set's fill (the nearest seen texel's material, the mesh's own normal), and
texels outside the UV charts their nearest sample texel's values (never a constant); coverage goes to extras
as a texture, or, with ``coverage_alpha``, into the base colour's alpha (``alphaMode`` MASK).
"""

from __future__ import annotations

import dataclasses
import json
import os
import struct
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ..io import UNSEEN_FILL, fill_unseen, read_maps, texel_surface
from ..materials import MODELS, MaterialMaps
from ..results import atomic_write_bytes
from ._gltf_textures import (
    GLTF_F0,
    GltfTextures,
    encode_material,
    fill_nearest,
    png_bytes,
    texel_frames,
    vertex_tangents,
)

__all__ = ["GltfExport", "write_gltf"]

FORMAT = "relight-gltf"
VERSION = 1
# glTF's lengths are metres; the stage frame's are millimetres.
M_PER_MM = 1e-3
# glTF enumerations (the 2.0 specification's tables).
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_FLOAT, _UNSIGNED_SHORT, _UNSIGNED_INT = 5126, 5123, 5125
_LINEAR, _LINEAR_MIPMAP_LINEAR, _CLAMP_TO_EDGE = 9729, 9987, 33071
_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
_DTYPES = {_FLOAT: np.float32, _UNSIGNED_SHORT: np.uint16, _UNSIGNED_INT: np.uint32}
SPECULAR, ANISOTROPY = "KHR_materials_specular", "KHR_materials_anisotropy"
_MAPPING = {
    "base_color": "rho_d / (1 - F0), sRGB, clamped to 1 (glTF scales its diffuse term by 1 - F)",
    "roughness": "sqrt(min(alpha_x, alpha_y)) in G; alpha = roughness^2; metallic 0 in B",
    "specular": "KHR_materials_specular: specular 1 (0 on lambert texels), colour F0 / F0_max (sRGB), "
                "colour factor F0_max / 0.04, so F0 = min(0.04 factor colour, 1) specular; F90 = specular",
    "anisotropy": "KHR_materials_anisotropy: strength s = sqrt((alpha_max - alpha_min) / (1 - alpha_min)) in B, "
                  "direction of alpha_max in RG (tangent space)",
    "normal": "tangent space of the interpolated NORMAL / TANGENT frame, B = w (N x T), +Y up the image",
    "blinn_phong": "GGX of the same alpha (alpha = sqrt(2 / (n + 2)) for exponent n), F0 = rho_s",
    "subsurface": "total diffuse reflectance as a local Lambert term (zero mean free path); mfp in extras",
}


@dataclasses.dataclass(frozen=True)
class GltfExport:
    """What :func:`write_gltf` wrote: the file, its size in bytes, the mesh's counts, the texture
    resolution (H, W), the texel samples per rung, the seen and filled (no camera saw them) texels, the
    texels whose value glTF could not hold (``clamped``: base colour above 1, normals beyond the horizon of
    the interpolated frame, fitted F0 above ``f0_max``) and the glTF extensions used."""

    path: Path
    bytes: int
    vertices: int
    faces: int
    resolution: tuple[int, int]
    rungs: dict
    seen: int
    filled: int
    clamped: dict
    extensions: tuple[str, ...]


@dataclasses.dataclass(frozen=True)
class _Source:
    """A map set's samples as the exporter takes them: the mesh (mm), the texel samples holding data, the
    maps there (NumPy), the resolution and what goes to extras."""

    mesh: object
    surface: object
    values: dict
    resolution: tuple[int, int]
    record: dict
    rig: dict | None


def _from_folder(folder: Path, mesh) -> _Source:
    import stage

    textures, info = read_maps(folder)
    where = str(folder / "maps.json")
    if mesh is None or isinstance(mesh, Mapping):
        mesh, full = texel_surface(info if mesh is None else mesh, textures.resolution, where=where)
    else:
        full = stage.texel_samples(mesh, textures.resolution)
    holds = textures.coverage | textures.filled
    idx = np.asarray(full.texel_index)
    on = holds.reshape(-1)[idx]
    missing = int(holds.sum() - on.sum())
    if missing:
        raise ValueError(f"{where}: {missing} texel(s) of the map set lie outside the UV atlas of mesh "
                         f"'{mesh.name}' at {textures.resolution[0]}x{textures.resolution[1]}: not the mesh the "
                         "maps were fitted on (give the right one)")
    surface = full.take(np.nonzero(on)[0])
    at = np.asarray(surface.texel_index)
    flat = lambda a: a.reshape((-1,) + a.shape[2:])[at]  # noqa: E731
    values = {"rho_d": flat(textures.albedo), "rho_s": flat(textures.specular), "alpha": flat(textures.alpha),
              "normal": flat(textures.normal), "tangent": flat(textures.tangent), "mfp": flat(textures.mfp),
              "model": flat(textures.model), "seen": flat(textures.coverage)}
    meta = textures.info.get("metadata", {}) or {}
    rig = None
    if isinstance(meta, Mapping) and meta.get("rig") and (folder / str(meta["rig"])).is_file():
        rig = stage.rig_to_dict(stage.load_rig(folder / str(meta["rig"])))
    record = {k: textures.info.get(k) for k in ("resolution", "surface", "unseen", "writer")}
    record["metadata"] = meta
    return _Source(mesh, surface, values, textures.resolution, record, rig)


def _from_maps(maps: MaterialMaps, mesh, surface, seen) -> _Source:
    import stage

    if surface is None or not isinstance(mesh, stage.Mesh):
        raise ValueError("write_gltf: MaterialMaps need the texel surface they are over (surface=) and its mesh "
                         "(mesh=, a stage.Mesh)")
    if maps.num_samples != surface.num_samples:
        raise ValueError(f"write_gltf: maps hold {maps.num_samples} samples but the surface has "
                         f"{surface.num_samples}")
    if surface.barycentric is None or len(np.unique(np.asarray(surface.texel_index))) != surface.num_samples:
        raise ValueError("write_gltf: the surface must be texel samples of the mesh (stage.texel_samples), one "
                         "per texel")
    P = surface.num_samples
    seen = np.ones(P, bool) if seen is None else np.asarray(seen, bool).reshape(P)
    if not seen.any():
        raise ValueError("write_gltf: no sample is seen (seen is all False)")
    if not seen.all():
        maps = fill_unseen(maps, surface, seen)  # the map set's fill: the nearest seen sample's material
    values = {k: np.asarray(getattr(maps, k)) for k in ("rho_d", "rho_s", "alpha", "normal", "tangent", "mfp",
                                                          "model")}
    values["seen"] = seen
    record = {"resolution": list(surface.resolution), "unseen": {"texels": int(P - seen.sum())}}
    return _Source(mesh, surface, values, tuple(surface.resolution), record, None)


class _Buffer:
    """The BIN chunk, built view by view (each 4-byte aligned), with the bufferViews and accessors on it."""

    def __init__(self):
        self.parts, self.size, self.views, self.accessors = [], 0, [], []

    def view(self, data: bytes, target: int | None = None) -> int:
        pad = -self.size % 4
        self.parts.append(b"\0" * pad)
        self.size += pad
        view = {"buffer": 0, "byteOffset": self.size, "byteLength": len(data)}
        if target is not None:
            view["target"] = target
        self.parts.append(data)
        self.size += len(data)
        self.views.append(view)
        return len(self.views) - 1

    def accessor(self, array: np.ndarray, kind: str, component: int, target: int, bounds: bool = False) -> int:
        a = np.ascontiguousarray(array, _DTYPES[component])
        acc = {"bufferView": self.view(a.tobytes(), target), "componentType": component,
               "count": int(a.shape[0]), "type": kind}
        if bounds:
            acc["min"] = [float(x) for x in a.reshape(a.shape[0], -1).min(0)]
            acc["max"] = [float(x) for x in a.reshape(a.shape[0], -1).max(0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def data(self) -> bytes:
        return b"".join(self.parts) + b"\0" * (-self.size % 4)


def _glb(doc: dict, binary: bytes) -> bytes:
    """The GLB container (glTF 2.0 section 4.4): header, JSON chunk (space-padded), BIN chunk (zero-padded)."""
    text = json.dumps(doc, separators=(",", ":"), allow_nan=False).encode("utf-8")
    text += b" " * (-len(text) % 4)
    total = 12 + 8 + len(text) + 8 + len(binary)
    return b"".join([struct.pack("<4sII", b"glTF", 2, total), struct.pack("<I4s", len(text), b"JSON"), text,
                     struct.pack("<I4s", len(binary), b"BIN\0"), binary])


def _images(tex: GltfTextures, at, resolution, coverage_alpha: bool) -> dict:
    """The texture images [H, W, C] by name: each sample's texel values, the other texels their nearest
    sample's (the coverage image: 0 off the samples)."""
    fill = lambda a: fill_nearest(a, at, resolution)  # noqa: E731
    base = tex.base
    if coverage_alpha:
        base = np.concatenate([base, tex.coverage[:, None]], -1)
    out = {"base_color": fill(base), "metallic_roughness": fill(tex.metal_rough), "normal": fill(tex.normal),
           "specular": fill(tex.specular), "rung": fill(tex.rung)}
    if tex.anisotropy is not None:
        out["anisotropy"] = fill(tex.anisotropy)
    if tex.mfp is not None:
        out["mean_free_path"] = fill(tex.mfp)
    cov = np.zeros(resolution[0] * resolution[1], np.uint8)
    cov[np.asarray(at)] = tex.coverage
    out["coverage"] = cov.reshape(resolution)
    return out


def _material(tex: GltfTextures, index: dict, coverage_alpha: bool) -> dict:
    k = float(tex.specular_color_factor)
    ext = {SPECULAR: {"specularFactor": 1.0, "specularTexture": {"index": index["specular"]},
                      "specularColorFactor": [k, k, k], "specularColorTexture": {"index": index["specular"]}}}
    if "anisotropy" in index:
        ext[ANISOTROPY] = {"anisotropyStrength": 1.0, "anisotropyTexture": {"index": index["anisotropy"]}}
    mat = {"name": "relight_maps",
           "pbrMetallicRoughness": {"baseColorTexture": {"index": index["base_color"]}, "metallicFactor": 1.0,
                                    "roughnessFactor": 1.0,
                                    "metallicRoughnessTexture": {"index": index["metallic_roughness"]}},
           "normalTexture": {"index": index["normal"]}, "doubleSided": False, "extensions": ext}
    if coverage_alpha:
        mat["alphaMode"], mat["alphaCutoff"] = "MASK", 0.5
    return mat


def _extras(src: _Source, tex: GltfTextures, index: dict, coverage_alpha: bool, rungs: dict) -> dict:
    seen = int(np.sum(src.values["seen"]))
    mfp = None
    if "mean_free_path" in index:
        mfp = {"texture": index["mean_free_path"], "unit": "mm", "scale_mm": tex.mfp_scale_mm,
               "encoding": "16-bit linear PNG, RGB: mean free path = value / 65535 * scale_mm"}
    return {"format": FORMAT, "version": VERSION,
            "units": {"length": "m", "source_length": "mm", "m_per_source_unit": M_PER_MM, "mean_free_path": "mm"},
            "frame": "relight's stage frame (x right, y up, z toward the main camera), glTF's +Y up, +Z front",
            "models": {str(i): m for i, m in enumerate(MODELS)}, "rungs": rungs, "mapping": _MAPPING,
            "specular_f0_max": tex.specular_color_factor * GLTF_F0,
            "rung": {"texture": index["rung"], "encoding": "8-bit, value = index into models"},
            "mean_free_path": mfp,
            "coverage": {"texture": index["coverage"], "seen": seen, "filled": len(src.values["seen"]) - seen,
                         "fill": UNSEEN_FILL, "alpha": coverage_alpha,
                         "encoding": "8-bit: 255 where a camera saw the texel, 0 elsewhere (fill, gutter)"},
            "clamped": tex.clamped, "maps": src.record, "rig": src.rig}


def _vertex_normals(mesh) -> np.ndarray:
    """The mesh's vertex normals made unit (glTF's NORMAL must be); a zero one (a file's) is replaced by the
    area-weighted normal of the vertex's triangles."""
    n = np.asarray(mesh.normals, np.float64)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    bad = length[:, 0] < 1e-12
    if bad.any():
        v, f = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)
        area = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        acc = np.zeros_like(v)
        for k in range(3):
            np.add.at(acc, f[:, k], area)
        n = np.where(bad[:, None], acc, n)
        length = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.where(length > 1e-12, length, 1.0) + np.where(length > 1e-12, 0.0, [[0.0, 0.0, 1.0]])


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("lightstage-relight")
    except PackageNotFoundError:  # running from a checkout
        return "unknown"


def write_gltf(maps, path: str | os.PathLike, *, mesh=None, surface=None, seen=None,
               coverage_alpha: bool = False, f0_max: float | None = None) -> GltfExport:
    """Write a fitted map set as one binary glTF 2.0 file (``.glb``) with a PBR material.

    The mapping of each rung onto glTF's metallic-roughness material with ``KHR_materials_specular`` and
    ``KHR_materials_anisotropy``, and what goes to extras, is the module docstring's (docs/export.md, with the
    measured difference per rung). Positions are converted from the stage frame's millimetres to glTF's
    metres; the mesh keeps its vertices and triangles (tangents added); textures are PNGs at the map set's
    resolution. The file is written atomically.

    Args:
        maps: a map-set folder (``relight.io.write_maps``'s: the texel surface is rebuilt from maps.json's mesh
            record), or ``relight.MaterialMaps`` over ``surface``.
        path: the ``.glb`` file to write (its folder must exist).
        mesh: for a folder, another mesh for the set (a ``relight.io.mesh_spec`` dict or a ``stage.Mesh`` in
            mm: the recorded one moved); for MaterialMaps, the ``stage.Mesh`` they are on (required).
        surface: for MaterialMaps, their ``stage.texel_samples`` surface (or a subset of it), one per texel.
        seen: for MaterialMaps, bool [P]: the samples a camera saw (None: all); the others are given the map
            set's fill first (``relight.io.fill_unseen``: the nearest seen sample's material, the mesh's normal).
        coverage_alpha: put the coverage in the base colour's alpha with ``alphaMode`` MASK (texels no camera
            saw cut out); default False: they keep the set's fill and the coverage is only in extras.
        f0_max: the F0 the specular colour texture spans (in (0, 1]); a higher fitted F0 is clamped to it and
            counted in the result's ``clamped["f0"]``. Default None: the largest F0 of a specular texel (nothing
            clamped). The texture is 8-bit sRGB of F0 / f0_max, so a few outliers at F0 ~ 1 cost the skin's
            F0 ~ 0.03 a step of ~4% (docs/export.md).

    Returns:
        A :class:`GltfExport`.

    Raises:
        FileNotFoundError / ImageFormatError naming the file for a missing or damaged map set; ValueError
        naming the problem for a path that is not ``.glb``, maps without their surface and mesh, or a mesh whose
        UV atlas does not hold the set's texels.

    References:
        The glTF 2.0 specification (Khronos, 2021), sections 3.7 (meshes), 3.9 (materials), 4.4 (GLB) and
        Appendix B (the BRDF); the KHR_materials_specular and KHR_materials_anisotropy extensions.
    """
    path = Path(path)
    if f0_max is not None and not (0.0 < f0_max <= 1.0):
        raise ValueError(f"write_gltf: f0_max must be in (0, 1], got {f0_max!r}")
    if path.suffix.lower() != ".glb":
        raise ValueError(f"{path}: a binary glTF file must end in .glb")
    if isinstance(maps, (str, os.PathLike)):
        src = _from_folder(Path(maps), mesh)
    elif isinstance(maps, MaterialMaps):
        src = _from_maps(maps, mesh, surface, seen)
    else:
        raise ValueError(f"write_gltf: maps must be a map-set folder or relight.MaterialMaps, got {type(maps)}")
    m, surf, v = src.mesh, src.surface, src.values
    if m.uv is None:
        raise ValueError(f"mesh '{m.name}' has no UV coordinates; a glTF export needs them")
    normals = _vertex_normals(m)
    tangents = vertex_tangents(m.vertices, m.faces, normals, m.uv)
    frames = texel_frames(normals, tangents, m.faces, np.asarray(surf.face), np.asarray(surf.barycentric))
    tex = encode_material(v["rho_d"], v["rho_s"], v["alpha"], v["normal"], v["tangent"], v["mfp"], v["model"],
                          v["seen"], frames, f0_max)
    images = _images(tex, surf.texel_index, src.resolution, coverage_alpha)

    buf = _Buffer()
    uv = np.asarray(m.uv, np.float64) * [1.0, -1.0] + [0.0, 1.0]  # glTF's v runs down the image
    attributes = {"POSITION": buf.accessor(np.asarray(m.vertices, np.float64) * M_PER_MM, "VEC3", _FLOAT,
                                           _ARRAY_BUFFER, bounds=True),
                  "NORMAL": buf.accessor(normals, "VEC3", _FLOAT, _ARRAY_BUFFER),
                  "TANGENT": buf.accessor(tangents, "VEC4", _FLOAT, _ARRAY_BUFFER),
                  "TEXCOORD_0": buf.accessor(uv, "VEC2", _FLOAT, _ARRAY_BUFFER)}
    n_vert = len(m.vertices)
    faces = np.asarray(m.faces).reshape(-1)
    indices = buf.accessor(faces, "SCALAR", _UNSIGNED_SHORT if n_vert <= 65535 else _UNSIGNED_INT,
                           _ELEMENT_ARRAY_BUFFER)
    index = {}
    doc_images, doc_textures = [], []
    for name, img in images.items():
        doc_images.append({"name": name, "mimeType": "image/png", "bufferView": buf.view(png_bytes(img))})
        doc_textures.append({"name": name, "sampler": 0, "source": len(doc_images) - 1})
        index[name] = len(doc_textures) - 1
    rungs = {name: int(np.sum(np.asarray(v["model"]) == i)) for i, name in enumerate(MODELS)}
    used = (SPECULAR,) + ((ANISOTROPY,) if "anisotropy" in index else ())
    doc = {"asset": {"version": "2.0", "generator": f"relight {_version()}"},
           "extensionsUsed": list(used), "scene": 0, "scenes": [{"nodes": [0]}],
           "nodes": [{"name": m.name, "mesh": 0}],
           "meshes": [{"name": m.name, "primitives": [{"attributes": attributes, "indices": indices, "material": 0,
                                                       "mode": 4}]}],
           "materials": [_material(tex, index, coverage_alpha)],
           "textures": doc_textures, "images": doc_images,
           "samplers": [{"magFilter": _LINEAR, "minFilter": _LINEAR_MIPMAP_LINEAR, "wrapS": _CLAMP_TO_EDGE,
                         "wrapT": _CLAMP_TO_EDGE}],
           "accessors": buf.accessors, "bufferViews": buf.views,
           "extras": {"relight": _extras(src, tex, index, coverage_alpha, rungs)}}
    binary = buf.data()
    doc["buffers"] = [{"byteLength": len(binary)}]
    data = _glb(doc, binary)
    atomic_write_bytes(path, lambda fh: fh.write(data))
    seen_n = int(np.sum(v["seen"]))
    return GltfExport(path, len(data), n_vert, len(m.faces), tuple(src.resolution), rungs, seen_n,
                      len(v["seen"]) - seen_n, dict(tex.clamped), used)

"""Reading back what :func:`relight.export.write_gltf` wrote: the GLB container parsed and checked, and the
material a glTF renderer sees decoded into relight's maps on a texel surface (to measure the export against
the fitted maps, docs/export.md)."""

from __future__ import annotations

import dataclasses
import json
import os
import struct
from pathlib import Path

import numpy as np

from ..io import ImageFormatError
from ..materials import MaterialMaps, material_maps
from ._gltf import ANISOTROPY, FORMAT, SPECULAR
from ._gltf_textures import GltfTextures, decode_material, png_pixels, texel_frames

__all__ = ["GltfAsset", "gltf_maps", "read_gltf"]

_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
_DTYPES = {5126: np.float32, 5121: np.uint8, 5123: np.uint16, 5125: np.uint32}


@dataclasses.dataclass(frozen=True)
class GltfAsset:
    """A binary glTF file as :func:`read_gltf` reads it: the JSON document, the first primitive's attributes
    (positions [V, 3] in the file's metres, normals [V, 3], tangents [V, 4], texcoords [V, 2] in glTF's
    convention, v down the image; triangles [F, 3]) and every image decoded ([H, W, C], uint8 or uint16)."""

    path: Path
    doc: dict
    positions: np.ndarray
    normals: np.ndarray
    tangents: np.ndarray | None
    texcoords: np.ndarray | None
    triangles: np.ndarray
    images: list

    @property
    def relight(self) -> dict:
        """The root's ``extras.relight`` (what relight wrote beside the glTF material), or {}."""
        return dict((self.doc.get("extras") or {}).get("relight") or {})


def _chunks(data: bytes, path: Path) -> tuple[dict, bytes]:
    """The JSON document and the BIN chunk of a GLB, its header and chunk lengths checked."""
    if len(data) < 20:
        raise ImageFormatError(f"{path}: not a binary glTF file ({len(data)} bytes)")
    magic, version, total = struct.unpack_from("<4sII", data, 0)
    if magic != b"glTF":
        raise ImageFormatError(f"{path}: not a binary glTF file (magic {magic!r}, expected b'glTF')")
    if version != 2:
        raise ImageFormatError(f"{path}: GLB container version {version}, expected 2")
    if total != len(data):
        raise ImageFormatError(f"{path}: the header says {total} bytes but the file has {len(data)} (truncated?)")
    chunks, at = [], 12
    while at < total:
        if at + 8 > total:
            raise ImageFormatError(f"{path}: a chunk header runs past the end of the file")
        length, kind = struct.unpack_from("<I4s", data, at)
        if length % 4 or at + 8 + length > total:
            raise ImageFormatError(f"{path}: chunk {kind!r} at byte {at} has a bad length {length}")
        chunks.append((kind, data[at + 8:at + 8 + length]))
        at += 8 + length
    if not chunks or chunks[0][0] != b"JSON":
        raise ImageFormatError(f"{path}: the first chunk must be JSON")
    try:
        doc = json.loads(chunks[0][1].decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ImageFormatError(f"{path}: the JSON chunk does not parse ({err})") from None
    binary = chunks[1][1] if len(chunks) > 1 and chunks[1][0] == b"BIN\0" else b""
    return doc, binary


def _view(doc: dict, binary: bytes, index: int, path: Path) -> bytes:
    try:
        v = doc["bufferViews"][index]
        start, length = int(v.get("byteOffset", 0)), int(v["byteLength"])
    except (KeyError, IndexError, TypeError, ValueError):
        raise ImageFormatError(f"{path}: bufferView {index} is missing or malformed") from None
    if start < 0 or start + length > len(binary):
        raise ImageFormatError(f"{path}: bufferView {index} runs past the BIN chunk")
    return binary[start:start + length]


def _accessor(doc: dict, binary: bytes, index: int, path: Path) -> np.ndarray:
    try:
        a = doc["accessors"][index]
        dtype, n, count = _DTYPES[a["componentType"]], _COMPONENTS[a["type"]], int(a["count"])
    except (KeyError, IndexError, TypeError, ValueError):
        raise ImageFormatError(f"{path}: accessor {index} is missing or of a kind this reader does not take") from None
    raw = _view(doc, binary, a["bufferView"], path)
    offset = int(a.get("byteOffset", 0))
    size = count * n * np.dtype(dtype).itemsize
    if doc["bufferViews"][a["bufferView"]].get("byteStride") or offset + size > len(raw):
        raise ImageFormatError(f"{path}: accessor {index} is strided or runs past its bufferView")
    return np.frombuffer(raw, dtype, count * n, offset).reshape(count, n)


def read_gltf(path: str | os.PathLike) -> GltfAsset:
    """Read a binary glTF 2.0 file's mesh (its first primitive) and images.

    Args:
        path: the ``.glb`` file (one buffer, the BIN chunk; tightly packed accessors, as :func:`write_gltf`
            writes them).

    Returns:
        A :class:`GltfAsset`.

    Raises:
        FileNotFoundError, or ImageFormatError naming the file: bad magic or version, a length that is not the
        file's, a chunk past the end, JSON that does not parse, an accessor or bufferView out of range.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such glTF file")
    doc, binary = _chunks(path.read_bytes(), path)
    try:
        prim = doc["meshes"][0]["primitives"][0]
        attr = prim["attributes"]
    except (KeyError, IndexError, TypeError):
        raise ImageFormatError(f"{path}: no mesh primitive") from None
    get = lambda name: _accessor(doc, binary, attr[name], path) if name in attr else None  # noqa: E731
    positions = get("POSITION")
    if positions is None or "indices" not in prim:
        raise ImageFormatError(f"{path}: the primitive needs POSITION and indices")
    triangles = _accessor(doc, binary, prim["indices"], path).reshape(-1, 3).astype(np.int64)
    images = [png_pixels(_view(doc, binary, im["bufferView"], path)) for im in doc.get("images", [])]
    return GltfAsset(path, doc, positions, get("NORMAL"), get("TANGENT"), get("TEXCOORD_0"), triangles, images)


def _texels(asset: GltfAsset, info: dict | None, at: np.ndarray, resolution) -> np.ndarray | None:
    """The pixels at the texel indices ``at`` ([P, C]) of the image of a textureInfo (``index``) or of an
    extras entry (``texture``)."""
    if info is None:
        return None
    img = asset.images[asset.doc["textures"][info["index" if "index" in info else "texture"]]["source"]]
    if img.shape[:2] != tuple(resolution):
        raise ImageFormatError(f"{asset.path}: a texture is {img.shape[0]}x{img.shape[1]} but the surface's grid "
                               f"is {resolution[0]}x{resolution[1]}")
    return img.reshape(-1, img.shape[2])[at]


def gltf_maps(glb, surface, *, extras: bool = False) -> MaterialMaps:
    """The material of a :func:`write_gltf` file as ``relight.MaterialMaps`` at a texel surface's samples.

    What a glTF renderer draws, in relight's model: each texture read at the samples' texels (no filtering),
    decoded by the inverse of the export's mapping (``relight.export._gltf_textures.decode_material``), the
    normal map in the frame the file's NORMAL and TANGENT interpolate to over each sample's triangle.

    Args:
        glb: a ``.glb`` path or a :class:`GltfAsset`.
        surface: ``stage.texel_samples`` of the exported mesh at the file's texture resolution (or a subset:
            the texels that hold data); its face indices are the file's triangles.
        extras: False (default): the rungs glTF draws (lambert, ggx or ggx_aniso; blinn_phong texels come back
            as GGX and subsurface ones as a local Lambert term); True: the rungs and mean free path recorded in
            the file's relight extras.

    Returns:
        ``relight.MaterialMaps`` over ``surface``.

    Raises:
        ImageFormatError naming the file when it is not a relight export or does not fit the surface.
    """
    asset = glb if isinstance(glb, GltfAsset) else read_gltf(glb)
    rel = asset.relight
    if rel.get("format") != FORMAT or asset.tangents is None:
        raise ImageFormatError(f"{asset.path}: not a relight glTF export (no extras.relight of format {FORMAT!r})")
    face = np.asarray(surface.face)
    if face.size and face.max() >= len(asset.triangles):
        raise ImageFormatError(f"{asset.path}: the surface's faces are not the file's ({len(asset.triangles)} "
                               "triangles)")
    mat = asset.doc["materials"][0]
    ext = mat.get("extensions", {})
    at, res = np.asarray(surface.texel_index), tuple(surface.resolution)
    px = lambda info: _texels(asset, info, at, res)  # noqa: E731
    pbr = mat["pbrMetallicRoughness"]
    mfp_info = rel.get("mean_free_path")
    tex = GltfTextures(
        base=px(pbr["baseColorTexture"]), metal_rough=px(pbr["metallicRoughnessTexture"]),
        specular=px(ext[SPECULAR]["specularTexture"]), normal=px(mat["normalTexture"]),
        anisotropy=px(ext[ANISOTROPY]["anisotropyTexture"]) if ANISOTROPY in ext else None,
        mfp=px(mfp_info) if mfp_info else None, rung=px(rel["rung"])[:, 0],
        coverage=px(rel["coverage"])[:, 0],
        specular_color_factor=float(ext[SPECULAR]["specularColorFactor"][0]),
        mfp_scale_mm=float(mfp_info["scale_mm"]) if mfp_info else 0.0, clamped={})
    frames = texel_frames(asset.normals, asset.tangents, asset.triangles, face, np.asarray(surface.barycentric))
    return material_maps(surface, **decode_material(tex, frames, extras=extras))

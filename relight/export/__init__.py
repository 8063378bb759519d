"""Exporters: a fitted texture set as a scene another renderer reads (Mitsuba 3's
XML, with the environment map resampled so that Mitsuba's lookups return
relight's pixels), or as one binary glTF 2.0 file with a PBR material
(``write_gltf``; ``read_gltf`` / ``gltf_maps`` read it back). See
docs/relight_io.md ("Exporters"), docs/export.md and docs/cli.md."""

from ._gltf import GltfExport as GltfExport
from ._gltf import write_gltf as write_gltf
from ._gltf_read import GltfAsset as GltfAsset
from ._gltf_read import gltf_maps as gltf_maps
from ._gltf_read import read_gltf as read_gltf
from ._mitsuba import mitsuba_envmap as mitsuba_envmap
from ._mitsuba import write_mitsuba_scene as write_mitsuba_scene

__all__ = ["GltfAsset", "GltfExport", "gltf_maps", "mitsuba_envmap", "read_gltf", "write_gltf", "write_mitsuba_scene"]

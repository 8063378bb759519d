"""File IO for the relighting tool: OpenEXR, Radiance HDR, PFM, PNG, capture
folders and DiLiGenT-style multi-light data, camera-space photo captures
(docs/capture_layout.md), texture sets, and texel-space
captures and map sets back to ``stage`` objects (``load_texel_capture``,
``load_texel_maps``), MERL measured BRDFs (``write_merl``). All writes are atomic
(``relight.results.atomic_path``; output folders are ``relight.results`` result sets); bad input
raises ``ImageFormatError`` (a ``ValueError``) naming the file and the problem.
See docs/relight_io.md for the formats and conventions."""

from ._capture import CaptureData as CaptureData
from ._capture import CaptureReader as CaptureReader
from ._capture import open_capture as open_capture
from ._capture import read_capture as read_capture
from ._capture import write_capture as write_capture
from ._capture_writer import CaptureFolderWriter as CaptureFolderWriter
from ._capture_writer import store_blocks as store_blocks
from ._diligent import DiligentData as DiligentData
from ._diligent import diligent_capture as diligent_capture
from ._diligent import grey_value as grey_value
from ._diligent import is_diligent_folder as is_diligent_folder
from ._diligent import lambert_normals as lambert_normals
from ._diligent import read_diligent as read_diligent
from ._errors import MAX_IMAGE_PIXELS as MAX_IMAGE_PIXELS
from ._errors import MAX_PATH_CHARS as MAX_PATH_CHARS
from ._errors import MAX_RADIANCE as MAX_RADIANCE
from ._errors import ImageFormatError as ImageFormatError
from ._errors import check_finite_output as check_finite_output
from ._errors import check_radiance as check_radiance
from ._errors import file_name as file_name
from ._exr import ExrPart as ExrPart
from ._exr import exr_header as exr_header
from ._exr import read_exr as read_exr
from ._exr import read_exr_channels as read_exr_channels
from ._exr import read_exr_parts as read_exr_parts
from ._exr import write_exr as write_exr
from ._exr import write_exr_channels as write_exr_channels
from ._exr import write_exr_parts as write_exr_parts
from ._hdr import RGBE_MAX as RGBE_MAX
from ._hdr import read_hdr as read_hdr
from ._hdr import read_hdr_header as read_hdr_header
from ._hdr import write_hdr as write_hdr
from ._json import jsonable as jsonable
from ._json import read_json as read_json
from ._json import write_json as write_json
from ._mean_free_path import mean_free_path_at as mean_free_path_at
from ._mean_free_path import read_mean_free_path as read_mean_free_path
from ._merl import write_merl as write_merl
from ._pfm import read_pfm as read_pfm
from ._pfm import write_pfm as write_pfm
from ._photo_check import PhotoCheck as PhotoCheck
from ._photo_check import check_photo_capture as check_photo_capture
from ._photo_store import photos_to_texel_store as photos_to_texel_store
from ._photo_texels import PhotoTexelReport as PhotoTexelReport
from ._photo_texels import photos_to_texels as photos_to_texels
from ._photo_writer import PhotoCaptureWriter as PhotoCaptureWriter
from ._photo_writer import write_photo_capture as write_photo_capture
from ._photos import PhotoCapture as PhotoCapture
from ._photos import PhotoView as PhotoView
from ._photos import is_photo_capture as is_photo_capture
from ._photos import read_photo_capture as read_photo_capture
from ._png import read_png as read_png
from ._png import write_png as write_png
from ._previews import write_map_previews as write_map_previews
from ._previews import write_preview as write_preview
from ._regions import read_regions as read_regions
from ._source import ArraySource as ArraySource
from ._source import CaptureSource as CaptureSource
from ._source import capture_source as capture_source
from ._source import valid_counts as valid_counts
from ._store import LIGHT_CHUNK as LIGHT_CHUNK
from ._store import CaptureStoreError as CaptureStoreError
from ._store import CaptureStoreWriter as CaptureStoreWriter
from ._store import StoreChangedError as StoreChangedError
from ._store import default_chunks as default_chunks
from ._store import is_capture_store as is_capture_store
from ._store import write_capture_store as write_capture_store
from ._store_partial import PartialStoreMismatch as PartialStoreMismatch
from ._store_reader import CaptureStore as CaptureStore
from ._store_reader import capture_folder_to_store as capture_folder_to_store
from ._store_reader import open_capture_store as open_capture_store
from ._store_reader import store_to_capture_folder as store_to_capture_folder
from ._texel import MESH_UNITS as MESH_UNITS
from ._texel import SampleSubset as SampleSubset
from ._texel import TexelCapture as TexelCapture
from ._texel import TexelMaps as TexelMaps
from ._texel import load_texel_capture as load_texel_capture
from ._texel import load_texel_maps as load_texel_maps
from ._texel import mesh_size_warning as mesh_size_warning
from ._texel import mesh_spec as mesh_spec
from ._texel import open_texel_capture as open_texel_capture
from ._texel import spec_mesh as spec_mesh
from ._texel import texel_surface as texel_surface
from ._texture_set import UNSEEN_FILL as UNSEEN_FILL
from ._texture_set import TextureSet as TextureSet
from ._texture_set import fill_unseen as fill_unseen
from ._texture_set import is_map_set as is_map_set
from ._texture_set import read_maps as read_maps
from ._texture_set import texture_set as texture_set
from ._texture_set import write_maps as write_maps
from ._texture_set import write_texture_set as write_texture_set
from ._texture_set import write_texture_set_files as write_texture_set_files
from ._textures import HEAD_SKIN_FILES as HEAD_SKIN_FILES
from ._textures import head_skin_textures as head_skin_textures
from ._textures import read_texture as read_texture
from ._yaleb import YALEB_DARK as YALEB_DARK
from ._yaleb import YALEB_INTENSITY as YALEB_INTENSITY
from ._yaleb import is_yaleb_folder as is_yaleb_folder
from ._yaleb import read_pgm as read_pgm
from ._yaleb import read_yaleb as read_yaleb
from ._yaleb import yaleb_direction as yaleb_direction

__all__ = [
    "ArraySource",
    "CaptureSource",
    "capture_source",
    "valid_counts",
    "CaptureFolderWriter",
    "store_blocks",
    "mean_free_path_at",
    "read_mean_free_path",
    "CaptureStore",
    "LIGHT_CHUNK",
    "CaptureStoreError",
    "CaptureStoreWriter",
    "StoreChangedError",
    "capture_folder_to_store",
    "default_chunks",
    "is_capture_store",
    "open_capture_store",
    "open_texel_capture",
    "store_to_capture_folder",
    "write_capture_store",
    "CaptureData",
    "CaptureReader",
    "DiligentData",
    "ExrPart",
    "HEAD_SKIN_FILES",
    "ImageFormatError",
    "RGBE_MAX",
    "MAX_RADIANCE",
    "MAX_PATH_CHARS",
    "MAX_IMAGE_PIXELS",
    "PartialStoreMismatch",
    "PhotoCapture",
    "PhotoCaptureWriter",
    "PhotoTexelReport",
    "PhotoView",
    "SampleSubset",
    "TexelCapture",
    "TexelMaps",
    "UNSEEN_FILL",
    "TextureSet",
    "check_finite_output",
    "check_radiance",
    "file_name",
    "exr_header",
    "head_skin_textures",
    "is_diligent_folder",
    "is_map_set",
    "is_photo_capture",
    "check_photo_capture",
    "jsonable",
    "lambert_normals",
    "grey_value",
    "load_texel_capture",
    "load_texel_maps",
    "MESH_UNITS",
    "mesh_size_warning",
    "mesh_spec",
    "open_capture",
    "photos_to_texel_store",
    "photos_to_texels",
    "PhotoCheck",
    "read_capture",
    "diligent_capture",
    "read_diligent",
    "YALEB_DARK",
    "YALEB_INTENSITY",
    "is_yaleb_folder",
    "read_pgm",
    "read_yaleb",
    "yaleb_direction",
    "read_exr",
    "read_exr_channels",
    "read_exr_parts",
    "read_hdr",
    "read_hdr_header",
    "read_json",
    "read_maps",
    "read_pfm",
    "read_regions",
    "read_texture",
    "read_photo_capture",
    "read_png",
    "spec_mesh",
    "texel_surface",
    "fill_unseen",
    "texture_set",
    "write_capture",
    "write_exr",
    "write_exr_channels",
    "write_exr_parts",
    "write_hdr",
    "write_json",
    "write_maps",
    "write_merl",
    "write_pfm",
    "write_photo_capture",
    "write_png",
    "write_map_previews",
    "write_preview",
    "write_texture_set",
    "write_texture_set_files",
]

"""File IO for the relighting tool: OpenEXR, Radiance HDR, PFM, PNG, capture
folders and DiLiGenT-style multi-light data. All writes are atomic; bad input
raises ``ImageFormatError`` (a ``ValueError``) naming the file and the problem.
See docs/relight_io.md for the formats and conventions."""

from ._capture import CaptureData as CaptureData
from ._capture import CaptureReader as CaptureReader
from ._capture import open_capture as open_capture
from ._capture import read_capture as read_capture
from ._capture import write_capture as write_capture
from ._diligent import DiligentData as DiligentData
from ._diligent import diligent_capture as diligent_capture
from ._diligent import read_diligent as read_diligent
from ._errors import ImageFormatError as ImageFormatError
from ._errors import check_radiance as check_radiance
from ._exr import ExrPart as ExrPart
from ._exr import exr_header as exr_header
from ._exr import read_exr as read_exr
from ._exr import read_exr_channels as read_exr_channels
from ._exr import read_exr_parts as read_exr_parts
from ._exr import write_exr as write_exr
from ._exr import write_exr_channels as write_exr_channels
from ._exr import write_exr_parts as write_exr_parts
from ._hdr import read_hdr as read_hdr
from ._hdr import read_hdr_header as read_hdr_header
from ._hdr import write_hdr as write_hdr
from ._pfm import read_pfm as read_pfm
from ._pfm import write_pfm as write_pfm
from ._png import read_png as read_png
from ._png import write_png as write_png
from ._mitsuba import write_mitsuba_scene as write_mitsuba_scene
from ._texture_set import TextureSet as TextureSet
from ._texture_set import is_map_set as is_map_set
from ._texture_set import read_maps as read_maps
from ._texture_set import write_maps as write_maps

__all__ = [
    "CaptureData",
    "CaptureReader",
    "DiligentData",
    "ExrPart",
    "ImageFormatError",
    "TextureSet",
    "check_radiance",
    "exr_header",
    "is_map_set",
    "open_capture",
    "read_capture",
    "diligent_capture",
    "read_diligent",
    "read_exr",
    "read_exr_channels",
    "read_exr_parts",
    "read_hdr",
    "read_maps",
    "read_hdr_header",
    "read_pfm",
    "read_png",
    "write_capture",
    "write_exr",
    "write_exr_channels",
    "write_exr_parts",
    "write_hdr",
    "write_maps",
    "write_mitsuba_scene",
    "write_pfm",
    "write_png",
]

"""Preview image operations: tone mapping (exposure, Reinhard / filmic curves),
the sRGB transfer, quantisation to 8/16 bits, and resampling."""

from ._image_ops import resize_image as resize_image
from ._tonemap import CURVES as CURVES
from ._tonemap import srgb_decode as srgb_decode
from ._tonemap import srgb_encode as srgb_encode
from ._tonemap import to_uint8 as to_uint8
from ._tonemap import to_uint16 as to_uint16
from ._tonemap import tonemap as tonemap

__all__ = ["CURVES", "resize_image", "srgb_decode", "srgb_encode", "to_uint8", "to_uint16", "tonemap"]

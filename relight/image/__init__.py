"""Preview images: the one auto-exposure rule (``subject_exposure``, metered on
the subject), tone mapping (exposure, Reinhard / filmic curves), the sRGB
transfer, quantisation to 8/16 bits, resampling, and texture-space previews
(texture lookups seen through a camera, gap dilation, whole-texel enlargement)."""

from ._comparison import psnr as psnr
from ._comparison import truth_fit_figure as truth_fit_figure
from ._coverage import coverage_image as coverage_image
from ._exposure import SUBJECT_KEY as SUBJECT_KEY
from ._exposure import SUBJECT_PERCENTILE as SUBJECT_PERCENTILE
from ._exposure import luminance as luminance
from ._exposure import subject_exposure as subject_exposure
from ._ops import resize_image as resize_image
from ._preview import BAND_RAYS as BAND_RAYS
from ._preview import PREVIEW_MIN_PX as PREVIEW_MIN_PX
from ._preview import dilate as dilate
from ._preview import row_bands as row_bands
from ._preview import sample_texture as sample_texture
from ._preview import texture_view as texture_view
from ._preview import upscale_nearest as upscale_nearest
from ._tonemap import CURVES as CURVES
from ._tonemap import srgb_decode as srgb_decode
from ._tonemap import srgb_encode as srgb_encode
from ._tonemap import to_uint8 as to_uint8
from ._tonemap import to_uint16 as to_uint16
from ._tonemap import tonemap as tonemap

__all__ = ["BAND_RAYS", "CURVES", "PREVIEW_MIN_PX", "SUBJECT_KEY", "SUBJECT_PERCENTILE", "coverage_image",
           "dilate", "luminance", "psnr", "resize_image", "row_bands", "truth_fit_figure",
           "sample_texture", "srgb_decode", "srgb_encode", "subject_exposure", "texture_view", "to_uint8", "to_uint16",
           "tonemap", "upscale_nearest"]

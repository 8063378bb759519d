"""Per-sample material maps: the model ladder (``MODELS``), the vectorised
ladder BRDF and :class:`MaterialMaps`, the one type that fitting produces and
rendering, the texture-set IO and the CLI consume."""

from ._demo import DEMO_F0 as DEMO_F0
from ._demo import demo_material as demo_material
from ._maps import ALPHA_MAX as ALPHA_MAX
from ._maps import BLINN_PHONG as BLINN_PHONG
from ._maps import GGX as GGX
from ._maps import GGX_ANISO as GGX_ANISO
from ._maps import LAMBERT as LAMBERT
from ._maps import MODELS as MODELS
from ._maps import RANGE_TOL as RANGE_TOL
from ._maps import SUBSURFACE as SUBSURFACE
from ._maps import LadderBRDF as LadderBRDF
from ._maps import MaterialMaps as MaterialMaps
from ._maps import material_maps as material_maps
from ._maps import phong_exponent as phong_exponent
from ._presets import preset_mean_free_path as preset_mean_free_path
from ._presets import subsurface_presets as subsurface_presets
from ._skin import ALBEDO_MAX as ALBEDO_MAX
from ._skin import ALBEDO_SCALE as ALBEDO_SCALE
from ._skin import ALPHA_RANGE as ALPHA_RANGE
from ._skin import EARS as EARS
from ._skin import F0_SKIN as F0_SKIN
from ._skin import LIPS as LIPS
from ._skin import NOSE as NOSE
from ._skin import REGION_MFP_GAIN as REGION_MFP_GAIN
from ._skin import REGION_NAMES as REGION_NAMES
from ._skin import SKIN as SKIN
from ._skin import SKIN_DMFP_MM as SKIN_DMFP_MM
from ._skin import SKIN_ETA as SKIN_ETA
from ._skin import SPEC_F0_RANGE as SPEC_F0_RANGE
from ._skin import SkinRegions as SkinRegions
from ._skin import SkinTruth as SkinTruth
from ._skin import skin_maps as skin_maps
from ._skin import skin_regions as skin_regions

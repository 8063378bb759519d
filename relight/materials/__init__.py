"""Per-sample material maps: the model ladder (``MODELS``), the vectorised
ladder BRDF and :class:`MaterialMaps`, the one type that fitting produces and
rendering, the texture-set IO and the CLI consume."""

from ._maps import BLINN_PHONG as BLINN_PHONG
from ._maps import GGX as GGX
from ._maps import GGX_ANISO as GGX_ANISO
from ._maps import LAMBERT as LAMBERT
from ._maps import MODELS as MODELS
from ._maps import SUBSURFACE as SUBSURFACE
from ._maps import LadderBRDF as LadderBRDF
from ._maps import MaterialMaps as MaterialMaps
from ._maps import material_maps as material_maps
from ._maps import phong_exponent as phong_exponent

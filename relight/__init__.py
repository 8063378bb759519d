"""relight: the application — file IO, environment maps, fitting with
Optimistix, image-based and model-based relighting, and the ``relight`` CLI."""

from ._fit import ALPHA_FIT_MIN as ALPHA_FIT_MIN, Fit as Fit, fit as fit
from ._maps import MODELS as MODELS, LadderBRDF as LadderBRDF, MaterialMaps as MaterialMaps
from ._maps import material_maps as material_maps, phong_exponent as phong_exponent

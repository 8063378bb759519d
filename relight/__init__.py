"""relight: the application — file IO, environment maps, fitting with
Optimistix, image-based and model-based relighting, and the ``relight`` CLI."""

from ._fit import ALPHA_FIT_MIN as ALPHA_FIT_MIN, FAILED_NONFINITE as FAILED_NONFINITE, Fit as Fit, fit as fit
from ._fit import LOSSES as LOSSES, PARAM_NAMES as PARAM_NAMES, SOLVERS as SOLVERS
from ._fit import rig_alpha_floor as rig_alpha_floor
from ._maps import MODELS as MODELS, LadderBRDF as LadderBRDF, MaterialMaps as MaterialMaps
from ._maps import material_maps as material_maps, phong_exponent as phong_exponent
from ._fit_sss import fit_subsurface as fit_subsurface

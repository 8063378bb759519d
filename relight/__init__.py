"""relight: the application — file IO (``relight.io``), environment maps
(``relight.envmap``), material maps (``relight.materials``), fitting with
Optimistix (``relight.fitting``), image-based and model-based relighting
(``relight.render``), preview images (``relight.image``) and the ``relight``
CLI (``relight.cli``, loaded on demand). See docs/ARCHITECTURE.md."""

from . import envmap as envmap
from . import fitting as fitting
from . import image as image
from . import io as io
from . import materials as materials
from . import render as render
from .fitting import ALPHA_FIT_MIN as ALPHA_FIT_MIN
from .fitting import FAILED_NONFINITE as FAILED_NONFINITE
from .fitting import LOSSES as LOSSES
from .fitting import PARAM_NAMES as PARAM_NAMES
from .fitting import SOLVERS as SOLVERS
from .fitting import Fit as Fit
from .fitting import fit as fit
from .fitting import fit_subsurface as fit_subsurface
from .fitting import fit_with_subsurface as fit_with_subsurface
from .fitting import rig_alpha_floor as rig_alpha_floor
from .materials import MODELS as MODELS
from .materials import LadderBRDF as LadderBRDF
from .materials import MaterialMaps as MaterialMaps
from .materials import material_maps as material_maps
from .materials import phong_exponent as phong_exponent

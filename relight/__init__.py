"""relight: the application — file IO (``relight.io``), environment maps
(``relight.envmap``), material maps (``relight.materials``), fitting with
Optimistix (``relight.fitting``), image-based and model-based relighting
(``relight.render``), preview images (``relight.image``), learned lighting
patterns (``relight.patterns``), the results viewer (``relight.view``), the demo
(``relight.demo``), result
sets and atomic writes (``relight.results``), exporters (``relight.export``),
simulated captures written whole (``relight.simulation``) and the ``relight``
CLI (``relight.cli``, loaded on demand). See docs/ARCHITECTURE.md.

The subpackages and the names re-exported here load on first use (PEP 562),
so ``relight --help`` and ``relight --version`` start without JAX."""

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the eager form, for type checkers and the architecture test's import graph
    from . import demo as demo
    from . import envmap as envmap
    from . import export as export
    from . import fitting as fitting
    from . import image as image
    from . import io as io
    from . import materials as materials
    from . import patterns as patterns
    from . import render as render
    from . import results as results
    from . import simulation as simulation
    from . import view as view
    from .fitting import ALPHA_FIT_MIN as ALPHA_FIT_MIN
    from .fitting import LOSSES as LOSSES
    from .fitting import PARAM_NAMES as PARAM_NAMES
    from .fitting import RESULTS as RESULTS
    from .fitting import SOLVERS as SOLVERS
    from .fitting import Fit as Fit
    from .fitting import FitOptions as FitOptions
    from .fitting import fit as fit
    from .fitting import fit_patterns as fit_patterns
    from .fitting import fit_subsurface as fit_subsurface
    from .fitting import fit_with_subsurface as fit_with_subsurface
    from .fitting import rig_alpha_floor as rig_alpha_floor
    from .materials import MODELS as MODELS
    from .materials import LadderBRDF as LadderBRDF
    from .materials import MaterialMaps as MaterialMaps
    from .materials import material_maps as material_maps
    from .materials import phong_exponent as phong_exponent

_SUBPACKAGES = ("demo", "envmap", "export", "fitting", "image", "io", "materials", "patterns", "render", "results",
                "simulation", "view")
# name -> the subpackage that defines it
_NAMES = {
    "ALPHA_FIT_MIN": "fitting",
    "RESULTS": "fitting",
    "FitOptions": "fitting",
    "LOSSES": "fitting",
    "PARAM_NAMES": "fitting",
    "SOLVERS": "fitting",
    "Fit": "fitting",
    "fit": "fitting",
    "fit_patterns": "fitting",
    "fit_subsurface": "fitting",
    "fit_with_subsurface": "fitting",
    "rig_alpha_floor": "fitting",
    "MODELS": "materials",
    "LadderBRDF": "materials",
    "MaterialMaps": "materials",
    "material_maps": "materials",
    "phong_exponent": "materials",
}
__all__ = [*_SUBPACKAGES, *_NAMES]


def __getattr__(name: str):
    """Import a subpackage, or the subpackage a re-exported name comes from, on first access."""
    if name in _SUBPACKAGES:
        return importlib.import_module(f".{name}", __name__)
    if name in _NAMES:
        value = getattr(importlib.import_module(f".{_NAMES[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))

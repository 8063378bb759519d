"""Property checks for any reflectance model with the common interface
``model(wi, wo) -> f_r`` (see ``brdf._check`` for the details)."""

from ._check import FAST_COMPILE as FAST_COMPILE
from ._check import directional_albedo as directional_albedo
from ._check import directional_albedo_mc as directional_albedo_mc
from ._check import edge_case_pairs as edge_case_pairs
from ._check import example_models as example_models
from ._check import hemisphere_quadrature as hemisphere_quadrature
from ._check import max_albedo as max_albedo
from ._check import min_value as min_value
from ._check import random_pairs as random_pairs
from ._check import reciprocity_error as reciprocity_error
from ._check import stability as stability

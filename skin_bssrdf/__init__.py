"""skin_bssrdf: subsurface scattering for the light stage.

Radial diffusion profiles R_d(r) (lengths in mm, R_d in 1/mm^2, per colour
channel), conversions between physical coefficients and (albedo, mean free
path), measured presets, and the surface diffusion operators that spread
irradiance between surface samples (sparse 3-D kernel, texture-space blurs).
"""

from ._better_dipole import BetterDipole as BetterDipole
from ._burley import SCALE_FITS as SCALE_FITS
from ._burley import Burley as Burley
from ._common import AbstractProfile as AbstractProfile
from ._common import fresnel_diffuse_reflectance as fresnel_diffuse_reflectance
from ._common import fresnel_moments as fresnel_moments
from ._convert import albedo_from_coefficients as albedo_from_coefficients
from ._convert import coefficients_from_albedo as coefficients_from_albedo
from ._convert import reduced_albedo_from_total as reduced_albedo_from_total
from ._convert import total_from_reduced_albedo as total_from_reduced_albedo
from ._dipole import Dipole as Dipole
from ._gaussians import SumOfGaussians as SumOfGaussians
from ._gaussians import fit_sum_of_gaussians as fit_sum_of_gaussians
from ._multipole import Multipole as Multipole
from ._operator import DiffusionOperator as DiffusionOperator
from ._presets import JENSEN2001 as JENSEN2001
from ._presets import SKIN_ETA as SKIN_ETA
from ._presets import MeasuredMaterial as MeasuredMaterial
from ._presets import preset as preset
from ._radius import MIN_OPERATOR_RADIUS_MM as MIN_OPERATOR_RADIUS_MM
from ._radius import OPERATOR_ENERGY as OPERATOR_ENERGY
from ._radius import energy_radius as energy_radius
from ._radius import operator_radius as operator_radius
from ._radius import widest_operator_radius as widest_operator_radius
from ._texture import TextureSpaceDiffusion as TextureSpaceDiffusion
from ._texture import gaussian_blur as gaussian_blur
from ._texture import gaussian_kernel1d as gaussian_kernel1d

"""Relighting: image-based (``relight_olat``, Debevec et al. 2000) and
model-based (``render_samples``, ``render_view``, ``turntable``) from material
maps, a surface and an environment map. See docs/relight_render.md.

Model-based methods are equinox Modules that hold their settings and prepare and
shade themselves (``AbstractMethod``: ``prepare(env)``, ``geometry(...)``,
``shade(...)``), one module each: ``Rig`` (the environment sampled at a light
rig's lights, what OLAT data supports), ``Dense`` (quadrature over a lat-long
grid with ray-cast visibility), ``Lights`` (a median-cut light set of equal
energy, Debevec 2005), ``Fast`` (SH irradiance + split-sum specular + ambient
occlusion) and ``Reference`` (Monte Carlo with multiple importance sampling).
``METHODS`` are their string spellings (the CLI's), turned into Modules by
``method_from_name``.

Image-based: ``image_based_view`` (a capture through a novel camera),
``relight_photographs`` (one camera's photographs), ``image_based_weights``;
``y_rotations`` turns the environment for either. A whole input folder into an
output folder (what ``relight render`` does): ``render_folder``.

What the camera sees besides the shading: ``pixel_coverage`` (a render's alpha), ``environment_behind`` (the
background to composite over), ``texel_fraction`` / ``uncovered_fraction`` (how much of the subject lies on
texels with data; ``seen_texels`` gives a capture's)."""

from ._abstract import AbstractMethod as AbstractMethod
from ._coverage import environment_behind as environment_behind
from ._coverage import pixel_coverage as pixel_coverage
from ._coverage import texel_fraction as texel_fraction
from ._coverage import uncovered_fraction as uncovered_fraction
from ._coverage import uncovered_pixels as uncovered_pixels
from ._dense import Dense as Dense
from ._dense import DenseLighting as DenseLighting
from ._directional import AbstractDirectional as AbstractDirectional
from ._directional import DirectionalGeometry as DirectionalGeometry
from ._directional import direction_visibility as direction_visibility
from ._fast import Fast as Fast
from ._fast import FastGeometry as FastGeometry
from ._fast import FastLighting as FastLighting
from ._folder import BACKGROUNDS as BACKGROUNDS
from ._folder import FRONT_SIZE as FRONT_SIZE
from ._folder import UNSEEN_WARN as UNSEEN_WARN
from ._folder import RenderedFolder as RenderedFolder
from ._folder import input_kind as input_kind
from ._folder import map_set_capture as map_set_capture
from ._folder import map_set_rig as map_set_rig
from ._folder import render_cameras as render_cameras
from ._folder import render_folder as render_folder
from ._folder import subsurface_settings as subsurface_settings
from ._folder import unseen_warnings as unseen_warnings
from ._image_based import image_based_view as image_based_view
from ._image_based import image_based_weights as image_based_weights
from ._image_based import nearest_view as nearest_view
from ._image_based import relight_photographs as relight_photographs
from ._image_based import seen_texels as seen_texels
from ._lights import Lights as Lights
from ._lights import LightsLighting as LightsLighting
from ._methods import DEFAULTS as DEFAULTS
from ._methods import METHODS as METHODS
from ._methods import method_from_name as method_from_name
from ._methods import render_samples as render_samples
from ._olat import relight_olat as relight_olat
from ._olat import relight_olat_sweep as relight_olat_sweep
from ._reference import Reference as Reference
from ._reference import ReferenceGeometry as ReferenceGeometry
from ._reference import ReferenceLighting as ReferenceLighting
from ._rig import Rig as Rig
from ._rig import RigLighting as RigLighting
from ._shading import build_operator as build_operator
from ._view import orbit_camera as orbit_camera
from ._view import render_view as render_view
from ._view import scaled_camera as scaled_camera
from ._view import turntable as turntable
from ._view import y_rotations as y_rotations

__all__ = [
    "AbstractDirectional",
    "AbstractMethod",
    "BACKGROUNDS",
    "DEFAULTS",
    "Dense",
    "DenseLighting",
    "DirectionalGeometry",
    "FRONT_SIZE",
    "Fast",
    "FastGeometry",
    "FastLighting",
    "Lights",
    "LightsLighting",
    "METHODS",
    "Reference",
    "ReferenceGeometry",
    "ReferenceLighting",
    "RenderedFolder",
    "Rig",
    "RigLighting",
    "UNSEEN_WARN",
    "build_operator",
    "direction_visibility",
    "environment_behind",
    "image_based_view",
    "image_based_weights",
    "input_kind",
    "map_set_capture",
    "map_set_rig",
    "method_from_name",
    "nearest_view",
    "orbit_camera",
    "pixel_coverage",
    "relight_olat",
    "relight_olat_sweep",
    "relight_photographs",
    "render_cameras",
    "render_folder",
    "render_samples",
    "render_view",
    "scaled_camera",
    "seen_texels",
    "subsurface_settings",
    "texel_fraction",
    "turntable",
    "uncovered_fraction",
    "uncovered_pixels",
    "unseen_warnings",
    "y_rotations",
]

"""Relighting: image-based (``relight_olat``, Debevec et al. 2000) and
model-based (``render_samples``, ``render_view``, ``turntable``) from material
maps, a surface and an environment map. See docs/relight_render.md.

Model-based methods (``METHODS``): "rig" (the environment sampled at a light
rig's lights, what OLAT data supports), "dense" (quadrature over a lat-long
grid with ray-cast visibility), "fast" (SH irradiance + split-sum specular +
ambient occlusion) and "reference" (Monte Carlo with multiple importance
sampling)."""

from ._olat import relight_olat as relight_olat
from ._olat import relight_olat_sweep as relight_olat_sweep
from ._methods import DEFAULTS as DEFAULTS
from ._methods import METHODS as METHODS
from ._methods import render_samples as render_samples
from ._view import orbit_camera as orbit_camera
from ._view import render_view as render_view
from ._view import turntable as turntable

__all__ = ["DEFAULTS", "METHODS", "orbit_camera", "relight_olat", "relight_olat_sweep", "render_samples",
           "render_view", "turntable"]

"""relight: the application — file IO, environment maps, fitting with
Optimistix, image-based and model-based relighting, and the ``relight`` CLI."""

from ._fit import ALPHA_FIT_MIN as ALPHA_FIT_MIN, Fit as Fit, fit as fit

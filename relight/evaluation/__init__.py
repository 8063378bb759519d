"""Scoring fits on data nobody here made: held-out-light prediction against the Lambertian baseline."""

from ._heldout import heldout_split as heldout_split
from ._heldout import lambert_least_squares as lambert_least_squares
from ._heldout import observation_validity as observation_validity
from ._heldout import predict_fit as predict_fit
from ._heldout import predict_lambert as predict_lambert
from ._heldout import relative_rms as relative_rms

__all__ = ["heldout_split", "lambert_least_squares", "observation_validity", "predict_fit", "predict_lambert",
           "relative_rms"]

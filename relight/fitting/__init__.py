"""Fitting per-sample reflectance to captures with Optimistix: the driver
(``fit``; how it runs: ``FitOptions``), its result (``Fit``, result codes
``RESULTS``), the solvers, the photometric-stereo start, the per-rung model and
its structured Jacobian, the model ladder, the subsurface fit (per region
or per texel, with its own ladder) and the fit to pattern captures
(``fit_patterns``); for inspecting and benchmarking the per-sample problems:
the packed ``observations``, the parameter ``Layout``, the start
(``start_parameters``), the model (``predict_radiance``,
``residual_and_jacobian``), a round of the solve (``solve_samples``) and the
per-texel subsurface data (``subsurface_texel_data``). See docs/fit.md."""

from ._driver import DEFAULT_LOSS as DEFAULT_LOSS
from ._driver import DEFAULT_MODEL as DEFAULT_MODEL
from ._driver import LOSSES as LOSSES
from ._driver import fit as fit
from ._folder import FitFolderResult as FitFolderResult
from ._folder import fit_diligent_folder as fit_diligent_folder
from ._folder import fit_folder as fit_folder
from ._joint import SUBSURFACE_LOSS as SUBSURFACE_LOSS
from ._joint import fit_with_subsurface as fit_with_subsurface
from ._joint import subsurface_radiance as subsurface_radiance
from ._lm import NormalLevenbergMarquardt as NormalLevenbergMarquardt
from ._model import Layout as Layout
from ._model import residual_and_jacobian as residual_and_jacobian
from ._options import FitOptions as FitOptions
from ._parts import PartsFingerprintError as PartsFingerprintError
from ._parts import PartsIncompleteError as PartsIncompleteError
from ._parts import fit_parts as fit_parts
from ._parts import merge_parts as merge_parts
from ._patterns import MIN_PATTERN_OBSERVATIONS as MIN_PATTERN_OBSERVATIONS
from ._patterns import fit_patterns as fit_patterns
from ._problem import Observations as Observations
from ._problem import SubsurfaceTexelData as SubsurfaceTexelData
from ._problem import observations as observations
from ._problem import predict_radiance as predict_radiance
from ._problem import solve_samples as solve_samples
from ._problem import start_parameters as start_parameters
from ._problem import subsurface_texel_data as subsurface_texel_data
from ._report import ERROR_ROWS as ERROR_ROWS
from ._report import angular_error_deg as angular_error_deg
from ._report import fit_report as fit_report
from ._report import flagged_summary as flagged_summary
from ._report import read_truth as read_truth
from ._report import report_markdown as report_markdown
from ._report import subsurface_report as subsurface_report
from ._report import truth_errors as truth_errors
from ._result import ALPHA_FIT_MIN as ALPHA_FIT_MIN
from ._result import MIN_OBSERVATIONS as MIN_OBSERVATIONS
from ._result import PARAM_NAMES as PARAM_NAMES
from ._result import RESULTS as RESULTS
from ._result import Fit as Fit
from ._result import result_code as result_code
from ._result import result_message as result_message
from ._result import rig_alpha_floor as rig_alpha_floor
from ._resume import fit_resumable as fit_resumable
from ._run import DILIGENT_LOSS as DILIGENT_LOSS
from ._run import DILIGENT_MODEL as DILIGENT_MODEL
from ._run import fit_diligent as fit_diligent
from ._run import subsurface_step as subsurface_step
from ._run import write_diligent_folder as write_diligent_folder
from ._shadows import SHADOW_RATIO as SHADOW_RATIO
from ._solvers import SOLVERS as SOLVERS
from ._solvers import resolve_solver as resolve_solver
from ._spd import SPDCholesky as SPDCholesky
from ._subsurface import fit_subsurface as fit_subsurface
from ._subsurface_texel import PRIOR_SIGMA_LN_MFP as PRIOR_SIGMA_LN_MFP
from ._write import write_fit_folder as write_fit_folder
from ._write import write_fit_maps as write_fit_maps
from ._write import write_report as write_report

"""The fit's per-sample problems, opened for inspection and benchmarks.

``relight.fit`` packs each sample's valid observations (:func:`observations`), starts from photometric
stereo and a roughness grid (:func:`start_parameters`) and refines the unconstrained parameters of a
:class:`~relight.fitting.Layout` with an Optimistix solver (:func:`solve_samples`) on the structured
residual ``residual_and_jacobian`` of the model :func:`predict_radiance`. ``relight.fit_subsurface``'s
per-texel rung solves, per texel and channel, a 2-parameter problem on data reduced over views
(:func:`subsurface_texel_data`). These functions are the ones the fitter calls, not copies: a benchmark
or a solver written against their arrays solves the fitter's problem (``scripts/bench_fit.py``,
``scripts/profile_fit_step.py``, ``scripts/bench_fit_subsurface.py``). docs/fit.md, "Inspecting the
per-sample problem".
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

import skin_bssrdf
import stage

from ..io import valid_counts
from . import _model as _fit_model
from . import _subsurface_texel as _tx
from ._driver import DEFAULT_BLOCK
from ._model import Layout
from ._observations import _obs_bucket, _observations
from ._result import Fit
from ._solvers import _solve_chunk, _start_chunk, resolve_solver
from ._sources import open_source
from ._subsurface import _reduced, _terms


class Observations(NamedTuple):
    """Per-sample packed observations (:func:`observations`): each valid (view, light) of a sample is
    one observation; the valid ones come first, then padding of weight 0 up to N.

    Attributes:
        radiance: [P, N, C] observed radiance (the capture's units).
        weight: [P, N, C] 1 for a valid observation, 0 for padding.
        wi: [P, N, 3] unit direction to the light in the sample's surface frame (z = the normal).
        wo: [P, N, 3] unit direction to the camera, same frame.
        irradiance: [P, N, C] the light's irradiance at normal incidence at the sample (the rig's units).
        light: [P, N] int, the light of each observation; None for arrays not packed from a capture.
    """

    radiance: np.ndarray
    weight: np.ndarray
    wi: np.ndarray
    wo: np.ndarray
    irradiance: np.ndarray
    light: np.ndarray | None = None


def observations(capture, surface: stage.Surface, *, n_keep: int | None = None, dtype=None) -> Observations:
    """Every sample's valid observations, packed as ``relight.fit`` packs them for its solver.

    Per sample, each (view, light) the capture marks valid becomes one observation with its local
    directions and irradiance (``stage.shading_directions``), valid ones first, then padding of
    weight 0. The arrays are in the capture's units: ``relight.fit`` further divides each sample's
    radiance and irradiance by its RMS irradiance (docs/fit.md, "Units and scale"), which changes no
    parameter of the model. The whole capture is read at once (``relight.fit`` reads it in blocks).

    Args:
        capture: a ``stage.Capture`` or a ``relight.io.CaptureSource``; sample p is ``surface``'s p.
        surface: the samples' ``stage.Surface`` (P samples).
        n_keep: observations per sample N; default the fit's: the most any sample has, rounded up to
            32, 64, 96, 128, then 1 or 1.5 times a power of two (192, 256, 384, ...).
        dtype: of the float arrays; default JAX's default float, as ``relight.fit``.

    Returns:
        :class:`Observations` of P samples.
    """
    source, _, _ = open_source(capture, "observations")
    P = int(source.shape[2])
    if surface.num_samples != P:
        raise ValueError(f"observations: capture has {P} samples but the surface has {surface.num_samples}")
    if n_keep is None:
        n_keep = _obs_bucket(int(np.max(valid_counts(source, DEFAULT_BLOCK), initial=0)))
    dt = np.dtype(jnp.result_type(float) if dtype is None else dtype)
    return Observations(*_observations(source, surface, 0, P, int(n_keep), dt))


def start_parameters(obs: Observations, layout: Layout) -> jax.Array:
    """The fitter's start for each sample, as unconstrained parameters.

    Photometric stereo (Woodham 1980) for the normal and the albedo on the lights least affected by
    specular reflection and shadow, then, for a rung with a specular lobe, closed-form albedos on a
    roughness grid (docs/fit.md, "How"); packed to the unconstrained vector of ``layout``.

    Args:
        obs: the samples' :class:`Observations` (P samples, N observations).
        layout: the rung's :class:`Layout`.

    Returns:
        u0 [P, layout.size] (entries ``layout.names``).
    """
    arrays = (obs.radiance, obs.weight, obs.wi, obs.wo, obs.irradiance)
    return _start_chunk(*(jnp.asarray(x) for x in arrays), layout)


def predict_radiance(u, layout: Layout, wi, wo, irradiance) -> jax.Array:
    """One sample's predicted radiance: the reference evaluation of the fitter's model.

    ``stage.reflected_radiance`` of the rung's BRDF composed from ``brdf``'s Modules (Lambert plus
    normalised Blinn-Phong or GGX microfacet with Schlick Fresnel and separable Smith masking), with
    the parameters of ``u`` and the directions turned into the fitted normal's frame (the view kept
    just above its horizon). ``residual_and_jacobian`` evaluates the same model on the solver's fast
    path. ``jax.vmap`` it for several samples.

    Args:
        u: [layout.size] unconstrained parameters (``layout.names``).
        layout: the rung's :class:`Layout`.
        wi, wo: [N, 3] unit directions to the light and the camera in the sample's surface frame.
        irradiance: [N, C] the light's irradiance at normal incidence.

    Returns:
        Radiance [N, C] (irradiance units x sr^-1).

    References:
        Walter et al. 2007, "Microfacet models for refraction through rough surfaces", eqs. 33-34;
        Schlick 1994, "An inexpensive BRDF model for physically-based rendering".
    """
    return _fit_model.predict(_fit_model.unpack(u, layout), layout, wi, wo, irradiance)


def solve_samples(
    u0,
    obs: Observations,
    layout: Layout,
    *,
    max_steps: int,
    solver="lm",
    cauchy: float | None = None,
    heldout_weight=None,
) -> tuple:
    """``max_steps`` steps of the fitter's solve for each sample, ``jax.vmap``-ed over the samples.

    Per sample: the Optimistix ``solver`` on the residual ``residual_and_jacobian`` from ``u0``, with
    the fitter's accept test (a solve that is not finite or raises the cost keeps its start, code
    ``RESULTS.rejected``) and the one-sigma uncertainties of the physical parameters from the
    Gauss-Newton covariance. One call is one round of ``relight.fit`` (which normalises the units
    first: :func:`observations`); it compiles once per (layout, solver, shapes).

    Args:
        u0: [P, layout.size] start (:func:`start_parameters`).
        obs: the samples' :class:`Observations` (NumPy or JAX arrays; ``light`` is not used).
        layout: the rung's :class:`Layout`.
        max_steps: solver steps.
        solver: a name of ``SOLVERS`` or an Optimistix solver object (:func:`resolve_solver`).
        cauchy: the Cauchy loss's scale relative to each sample's RMS radiance; None (default, as
            ``relight.fit``'s default loss): plain least squares.
        heldout_weight: [P, N, C] weights of held-out observations (scored, not fitted); default none.

    Returns:
        (u [P, size], rms [P] weighted RMS residual, result [P] int (``result_message``), steps [P],
        sigma [P, k] of the physical parameters (rho_d, then rho_s, alpha, ..., normal tilt),
        held-out mean squared error [P]).
    """
    solver = resolve_solver(solver)[0]
    h = jnp.zeros_like(obs.weight) if heldout_weight is None else heldout_weight
    return _solve_chunk(
        u0,
        obs.radiance,
        obs.weight,
        h,
        obs.wi,
        obs.wo,
        obs.irradiance,
        lay=layout,
        solver=solver,
        max_steps=int(max_steps),
        cauchy=None if cauchy is None else float(cauchy),
    )


class SubsurfaceTexelData(NamedTuple):
    """The per-texel subsurface problem of some texels (:func:`subsurface_texel_data`): per texel and
    light, the observations reduced over views, and the texel's gathered transmitted irradiance.

    Per texel, light l and channel: sum_v m_vl (y_vl - A f_v S_l)^2 = weight_l (A S_l - exitance_l)^2 +
    constant_l, with y the observation minus the fitted specular, m its validity, f_v = F_t(cos_o)/pi
    and S_l = self_l w_self(d) + neighbour_l . w(distance; d) the exitance per unit albedo for the
    profile's shape length d = mfp / s(A). Radiance and irradiance are divided by ``unit``.

    Attributes:
        texels: [n] int, the texels (indices into the surface).
        weight: [n, L] sum over valid views of f_v^2 (sr^-2).
        exitance: [n, L, C] the observed exitance A S_l, sum_v m f_v y / weight (0 where weight is 0),
            / unit.
        constant: [n, L, C] sum_v m y^2 - weight exitance^2, / unit^2.
        count: [n, L] valid views per light.
        self_irradiance: [n, C, L] the texel's own transmitted irradiance, / unit.
        neighbour_irradiance: [n, C, L, K] its operator neighbours', times their area (mm^2; 0 for
            padding), / unit.
        distance: [n, K] to the neighbours (mm).
        self_radius: [n] the radius of the texel's own disc (mm).
        unit: [n] the texel's RMS transmitted irradiance over the lights with a valid view.
        noise_floor: [n, C] the variance floor of the prior's scale (1e-3 of the RMS observation, squared).
    """

    texels: np.ndarray
    weight: np.ndarray
    exitance: np.ndarray
    constant: np.ndarray
    count: np.ndarray
    self_irradiance: np.ndarray
    neighbour_irradiance: np.ndarray
    distance: np.ndarray
    self_radius: np.ndarray
    unit: np.ndarray
    noise_floor: np.ndarray


def subsurface_texel_data(
    capture: stage.Capture,
    surface: stage.Surface,
    fitted: Fit,
    operator: skin_bssrdf.DiffusionOperator,
    texels=None,
    *,
    eta: float = skin_bssrdf.SKIN_ETA,
    dtype=None,
) -> SubsurfaceTexelData:
    """The data of ``relight.fit_subsurface``'s per-texel solve, for ``texels``, on every light.

    The observations minus the specular lobe ``fitted`` (held fixed) are reduced exactly over views
    and each texel's transmitted irradiance (``stage.subsurface_irradiance``) is gathered over its
    neighbourhood in ``operator``: what the texel solver keeps for every step. With Christensen &
    Burley's unit-albedo profile (``skin_bssrdf.Burley``, the "dmfp" scaling) a texel-channel's
    data residual is sqrt(weight) (A S(mfp, A) - exitance); ``relight.fit_subsurface`` adds a prior on
    ln mfp of width ``PRIOR_SIGMA_LN_MFP`` scaled by the data's RMS residual plus ``noise_floor``.
    docs/fit.md, "Per-texel subsurface". Memory: n x C x L x (K + 1) floats.

    Args:
        capture: the OLAT ``stage.Capture`` [V, L, P, C].
        surface: its ``stage.Surface``.
        fitted: the BRDF ``Fit`` of ``relight.fit`` (its lobe and normals).
        operator: the ``skin_bssrdf.DiffusionOperator`` of the surface (neighbours K per texel).
        texels: int [n] indices of the texels; default all P.
        eta: the relative index of refraction of the transmission terms.
        dtype: of the gathered irradiance; default JAX's default float, as ``relight.fit_subsurface``.

    Returns:
        :class:`SubsurfaceTexelData` of the n texels.

    References:
        Christensen & Burley 2015, "Approximate reflectance profiles for efficient subsurface
        scattering", eqs. 2-3, 8 and 11; Jensen et al. 2001, "A practical model for subsurface light
        transport", eq. 5.
    """
    dt = jnp.result_type(float) if dtype is None else dtype
    y, valid, E, wo, _ = _terms(capture, surface, fitted, eta)
    data, unit = _reduced(y, valid, E, wo, eta, dt)
    geo = _tx.Geometry.of(operator, dt)
    idx = np.arange(surface.num_samples) if texels is None else np.asarray(texels)
    a, ybar, c0, count = _tx._normalised(data, np.arange(E.shape[0]), unit, idx)
    Gs, Gn = _tx._gather(jnp.asarray(idx), jnp.asarray(E, dt), geo.index, geo.weight, jnp.asarray(unit[idx], dt))
    # _stats per texel and channel on every light (the light weights of a full fit: 1).
    stats = jax.vmap(jax.vmap(_tx._stats, in_axes=(1, None, 1, None, None)))
    _, floor = stats(ybar, a, c0, count, np.ones_like(a))
    return SubsurfaceTexelData(
        idx,
        a,
        ybar,
        c0,
        count,
        np.asarray(Gs),
        np.asarray(Gn),
        np.asarray(geo.distance)[idx],
        np.asarray(geo.rho)[idx],
        unit[idx],
        np.asarray(floor, np.float64),
    )

"""Per-sample reflectance fitting with Optimistix, and the model ladder.

Per sample (texel or pixel) the fitter finds, by least squares over every
(view, light, channel) observation the capture marks valid, the parameters of
one rung of the ladder (``relight.MODELS``): Lambert; + normalised
Blinn-Phong; + isotropic GGX (Walter et al. 2007, Smith masking, Schlick
Fresnel with F0 = the specular albedo: the form Kang et al. 2018 fit);
+ anisotropic GGX with its tangent angle; optionally the shading normal.

1. start (:mod:`relight.fitting._init`): photometric stereo on the lights least
   affected by specular reflection and shadow, then closed-form albedos on a
   roughness grid;
2. refine: ``optimistix.least_squares`` (Levenberg-Marquardt by default;
   any Optimistix least-squares solver or minimiser object, or by name
   Gauss-Newton, Dogleg, BFGS), ``jax.vmap`` over a chunk of
   samples, chunks over the sample axis so memory is bounded by the chunk,
   rounds of a few steps with only the unconverged samples going on (packed
   into full chunks: "straggler compaction"); a Cauchy loss so cast shadows and
   interreflections do not drag the fit;
3. ``model="auto"``: every rung is fitted on the training lights and scored
   on held-out lights; each sample gets the simplest rung whose held-out error
   is within noise of the best, then is refitted on all lights.

Subsurface (mean free path) is fitted afterwards, across samples, by
:func:`relight.fit_subsurface`.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jaxtyping import Array, Float, Int

import stage

from ..materials._maps import (
    BLINN_PHONG,
    GGX,
    GGX_ANISO,
    LAMBERT,
    MODELS,
    SUBSURFACE,
    LadderBRDF,
    MaterialMaps,
    material_maps,
)
from . import _init as _fit_init
from . import _model as _fit_model
from ._lm import NormalLevenbergMarquardt
from ._model import Layout

# The fitter's roughness prior, separate from the model's own floor
# (brdf.ALPHA_MIN): below this no light stage resolves a GGX lobe.
ALPHA_FIT_MIN = 0.02
SOLVERS = ("lm", "optx-lm", "gn", "dogleg", "bfgs")
LOSSES = ("cauchy", "l2")
# Every parameter a rung may report an uncertainty for (0 where not fitted, inf where unknown).
PARAM_NAMES = ("rho_d.r", "rho_d.g", "rho_d.b", "rho_s", "alpha_x", "alpha_y", "phi", "normal.x", "normal.y")
# Fewer valid observations (lights x views) than this leave a sample underdetermined.
_MIN_OBSERVATIONS = 8
# Result code for a sample whose solve produced a non-finite value or a worse
# cost than its start (it keeps its start): optimistix's own codes are 0..8.
FAILED_NONFINITE = 100
_MAX_STEPS_CODE = int(optx.RESULTS.nonlinear_max_steps_reached._value)


def rig_alpha_floor(rig: stage.Rig) -> float:
    """The smallest GGX roughness a rig's angular light spacing resolves.

    A GGX lobe's half width at half maximum is about 0.64 alpha in the half
    vector, so about 1.3 alpha in light direction, and its full width about 2.6
    alpha; with lights a median nearest-neighbour angle Delta apart, at least
    two lights fall across the lobe only for alpha >= Delta / 2.6 (Light Stage X:
    Delta ~ 0.19 rad, floor ~ 0.07). Never below ``ALPHA_FIT_MIN``."""
    d = np.asarray(rig.directions, np.float64)
    if len(d) < 2:
        return ALPHA_FIT_MIN
    cos = np.clip(d @ d.T, -1.0, 1.0)
    np.fill_diagonal(cos, -1.0)
    spacing = float(np.median(np.arccos(cos.max(axis=1))))
    return float(max(ALPHA_FIT_MIN, spacing / 2.6))


class Fit(eqx.Module):
    """The result of :func:`fit`, per sample: parameter maps (rho_d [P, 3],
    rho_s [P, 1], alpha [P, 2] along the fitted tangent / bitangent, normal and
    tangent [P, 3] in world space), the ladder rung (``model`` [P], index into
    ``relight.MODELS``), the RMS residual [P] (all valid observations, in the
    capture's radiance units), the held-out RMS [P] (``model="auto"``; else 0;
    the capture's units), the
    Optimistix result code [P] (0 = successful; FAILED_NONFINITE = the solve
    was rejected and the sample kept its start), LM steps taken [P], valid
    observations [P], one-sigma uncertainties [P, 9] from J^T J (names in
    ``PARAM_NAMES``, in the parameters' units, 0 where a rung has no such
    parameter, inf where the data leave a fitted parameter unknown: no or too
    few observations, a direction nothing constrains; ``unidentified``
    flags those), and the roughness
    floor the rig resolves (``alpha_floor``: a fitted alpha at the floor means
    "narrower than the rig can tell", flagged by ``unresolved``), the mean
    free path [P, 3] (mm; after :func:`relight.fit_subsurface`, else None) and
    the solver's name (``solver``: the string given to :func:`fit`, or the
    class and tolerances of the Optimistix solver object). ``min_observed``
    (static): the fewest valid observations a sample needs (``failed`` below
    it): 8 (lights x views) for :func:`fit`, 4 pattern measurements for
    :func:`relight.fitting.fit_patterns`.

    After :func:`relight.fit_subsurface` (else None): ``mfp_sigma`` [P, 3], the
    1-sigma of ln(mfp) per channel from the data alone (s^2 (J^T J)^-1 with the
    albedo marginalised, the prior left out; for a per-region texel the
    region's shared value's, the texels' informations summed; inf where not
    identifiable or no subsurface), ``mfp_rung`` [P] int32 (0 = no subsurface:
    the BRDF's local Lambert term, mfp 0; 1 = the region's mean free path; 2 =
    the texel's own) and the property ``mfp_identified`` [P, 3] (sigma below
    ``Fit.IDENTIFIED_SIGMA`` = 0.25). ``model`` is SUBSURFACE where
    ``mfp_rung`` > 0."""

    rho_d: Float[Array, "sample 3"]
    rho_s: Float[Array, "sample 1"]
    alpha: Float[Array, "sample 2"]
    normal: Float[Array, "sample 3"]
    tangent: Float[Array, "sample 3"]
    model: Int[Array, " sample"]
    residual: Float[Array, " sample"]
    heldout: Float[Array, " sample"]
    result: Int[Array, " sample"]
    steps: Int[Array, " sample"]
    observed: Float[Array, " sample"]
    uncertainty: Float[Array, "sample 9"]
    alpha_floor: float = eqx.field(static=True, default=ALPHA_FIT_MIN)
    mfp: Float[Array, "sample 3"] | None = None
    solver: str = eqx.field(static=True, default="lm")
    mfp_sigma: Float[Array, "sample 3"] | None = None
    mfp_rung: Int[Array, " sample"] | None = None
    # Fewer valid observations than this leave a sample underdetermined (``failed``): _MIN_OBSERVATIONS
    # (lights x views) for an OLAT fit; for relight.fitting.fit_patterns, pattern measurements (views x patterns).
    min_observed: int = eqx.field(static=True, default=_MIN_OBSERVATIONS)
    # ambiguous's bar on the albedo's relative 1-sigma.
    AMBIGUOUS_RELATIVE_SIGMA: ClassVar[float] = 0.1
    # mfp_identified's bar on the 1-sigma of ln mfp: 25% relative.
    IDENTIFIED_SIGMA: ClassVar[float] = 0.25

    @property
    def f0(self):
        """The specular albedo as Schlick's F0 [P, 1] (same as ``rho_s``)."""
        return self.rho_s

    @property
    def failed(self):
        """Samples whose solve failed or that had too few observations."""
        return (self.result != 0) | (self.observed < self.min_observed)

    @property
    def mfp_identified(self):
        """[P, 3] bool: texel-channels whose mean free path the data pin to a 1-sigma of ln mfp below
        IDENTIFIED_SIGMA (0.25); None before :func:`relight.fit_subsurface`."""
        if self.mfp_sigma is None:
            return None
        return jnp.isfinite(self.mfp_sigma) & (self.mfp_sigma < self.IDENTIFIED_SIGMA)

    @property
    def ambiguous(self):
        """[P] bool: samples whose albedo the data leave loose, a 1-sigma above
        ``AMBIGUOUS_RELATIVE_SIGMA`` (10%) of rho_d in some channel (or
        unknown). Noise then lets a broad grey lobe trade places with the
        diffuse term at an equal or lower cost than the truth: on a 162-light
        dome at 1000 photons every texel below 0.8x its true albedo is flagged
        (tests/relight/test_fit_ambiguous.py at 100 photons on a sphere)."""
        rel = self.uncertainty[:, :3] / jnp.maximum(self.rho_d, 1e-6)
        return jnp.any(~(rel <= self.AMBIGUOUS_RELATIVE_SIGMA), axis=1) & (self.observed >= self.min_observed)

    @property
    def unidentified(self):
        """[P, 9] bool (``PARAM_NAMES``): fitted parameters the data leave unknown (uncertainty inf)."""
        return ~jnp.isfinite(self.uncertainty)

    @property
    def unresolved(self):
        """Samples whose lobe is at the rig's roughness floor (sharper than it resolves)."""
        return (self.model >= BLINN_PHONG) & (self.alpha[:, 0] < 1.25 * self.alpha_floor)

    def maps(self, surface: stage.Surface) -> MaterialMaps:
        """The fit as material maps over ``surface`` (the fitted frame and rungs)."""
        mfp = None if self.mfp is None else self.mfp
        return material_maps(surface, self.rho_d, self.rho_s, self.alpha, normal=self.normal, tangent=self.tangent,
                             mfp=mfp, model=self.model)

    def material(self) -> LadderBRDF:
        """The fitted BRDF (leading sample axis), in the fitted frame."""
        return LadderBRDF(self.rho_d, self.rho_s, self.alpha, self.model[:, None], include_diffuse=True)


# The string spellings of ``fit(solver=...)`` (the CLI's --method) and their
# tolerances. Normal equations + Cholesky: the systems are 3-9 wide and, with
# LM's damping, well conditioned; several times cheaper than QR of [N, p].
_RTOL, _ATOL = 1e-5, 1e-6


def _named_solver(name: str, rtol: float, atol: float):
    """The Optimistix solver a string spelling stands for."""
    chol = lx.Normal(lx.Cholesky())
    if name == "lm":
        return NormalLevenbergMarquardt(rtol=rtol, atol=atol)
    if name == "optx-lm":
        return optx.LevenbergMarquardt(rtol=rtol, atol=atol, linear_solver=chol)
    if name == "gn":
        return optx.GaussNewton(rtol=rtol, atol=atol, linear_solver=chol)
    if name == "dogleg":
        return optx.Dogleg(rtol=rtol, atol=atol, linear_solver=chol)
    return optx.BFGS(rtol=rtol, atol=atol)


def _solver_name(solver) -> str:
    """A short name of an Optimistix solver object for reports: its class and tolerances."""
    tol = ", ".join(f"{k}={getattr(solver, k):g}" for k in ("rtol", "atol")
                    if isinstance(getattr(solver, k, None), (int, float)))
    return f"{type(solver).__name__}({tol})"


def resolve_solver(solver, rtol: float | None = None, atol: float | None = None):
    """(Optimistix solver, name) for ``fit``'s ``solver`` argument: a string of
    ``SOLVERS`` (built with ``rtol`` / ``atol``, default 1e-5 / 1e-6, and the
    normal-equations Cholesky linear solver) or an Optimistix least-squares
    solver or minimiser object, used as it is (it carries its own tolerances,
    so ``rtol`` / ``atol`` must then be None). Raises ValueError / TypeError
    naming ``solver`` otherwise."""
    if isinstance(solver, str):
        if solver not in SOLVERS:
            raise ValueError(f"fit: solver must be one of {SOLVERS} or an Optimistix solver object, got {solver!r}")
        rtol = _RTOL if rtol is None else float(rtol)
        atol = _ATOL if atol is None else float(atol)
        if not (rtol >= 0 and atol >= 0):
            raise ValueError(f"fit: rtol and atol must be >= 0, got rtol={rtol}, atol={atol}")
        return _named_solver(solver, rtol, atol), solver
    if isinstance(solver, (optx.AbstractLeastSquaresSolver, optx.AbstractMinimiser)):
        if rtol is not None or atol is not None:
            raise ValueError(f"fit: rtol / atol apply to a solver given by name; the solver object "
                             f"{_solver_name(solver)} carries its own tolerances")
        return solver, _solver_name(solver)
    raise TypeError(f"fit: solver must be one of {SOLVERS} or an Optimistix solver object "
                    f"(optx.AbstractLeastSquaresSolver or optx.AbstractMinimiser, e.g. "
                    f"optx.LevenbergMarquardt(rtol=1e-5, atol=1e-6)), got {type(solver).__name__}: {solver!r}")


@jax.jit(static_argnames=("lay",))
def _start_chunk(obs, w, wi, wo, irr, lay):
    """Start for each sample, packed to the unconstrained parameters [Pc, size]."""
    return jax.vmap(lambda *a: _fit_model.pack(_fit_init.start(*a, lay), lay))(obs, w, wi, wo, irr)


def solve_one(rj, u0, n_weight, n_entries: int, lay: Layout, solver, max_steps: int):
    """One sample's solve, shared by :func:`fit` and :func:`relight.fitting.fit_patterns`.

    ``rj(u) -> (r [m], J [m, k], ...)``: the robust residual and its
    structured Jacobian (anything after them is returned as it is).
    ``n_weight``: the residual's total weight (the valid observations x
    channels: the noise estimate's degrees of freedom before the k
    parameters); ``n_entries`` (static): m, for the rounding slack of the
    accept test. ``max_steps`` steps of the Optimistix ``solver`` from u0
    (NormalLevenbergMarquardt on the normal equations of ``rj``, any other
    through the custom-JVP residual :func:`relight.fitting._model.materialised`);
    the solve is kept only if it is finite and does not raise the cost (else
    the start, code FAILED_NONFINITE). Returns (u, code, steps, sigma [k'] of
    the physical parameters (:func:`relight.fitting._model.physical_vector`),
    rj(u))."""
    res = _fit_model.materialised(rj)
    if isinstance(solver, NormalLevenbergMarquardt):  # it takes the structured normal equations as fn's aux
        def normal(u, _):
            r, J = rj(u)[:2]
            return r, (J.T @ J, J.T @ r)

        sol = optx.least_squares(normal, solver, u0, has_aux=True, options={"jac": "normal"},
                                 max_steps=max_steps, throw=False)
    else:
        sol = optx.least_squares(lambda u, _: res(u), solver, u0, max_steps=max_steps, throw=False)
    u1 = sol.value
    cost0 = jnp.sum(res(u0) ** 2)
    cost1 = jnp.sum(res(u1) ** 2)
    # Reject only a real increase: the slack is 1e-6 plus the worst-case
    # rounding of a sum of n = 3N squares in this dtype, about n eps (Higham
    # 2002, ch. 4). Near the optimum float32 costs differ by that much (LM
    # accepts steps whose predicted reduction is ~0): 1e-6 alone flagged 1-2%
    # of samples FAILED_NONFINITE in float32 by rounding. float64: unchanged.
    slack = 1e-6 + n_entries * float(jnp.finfo(u0.dtype).eps)
    good = jnp.all(jnp.isfinite(u1)) & jnp.isfinite(cost1) & (cost1 <= cost0 * (1 + slack) + 1e-30)
    u = jnp.where(good, u1, u0)
    code = jnp.where(good, sol.result._value, FAILED_NONFINITE)
    final = rj(u)
    r_u, J = final[:2]
    # One-sigma uncertainties from the Gauss-Newton covariance s^2 (J^T J)^-1
    # of the (robust) residual, mapped to the physical parameters.
    k = u.shape[0]
    dof = jnp.maximum(n_weight - k, 1.0)
    s2 = jnp.sum(r_u ** 2) / dof
    jtj = J.T @ J
    ridge = 1e-9 * (jnp.trace(jtj) / k + 1e-30)
    cov = s2 * jnp.linalg.inv(jtj + ridge * jnp.eye(k, dtype=u.dtype))
    Jp = jax.jacfwd(lambda v: _fit_model.physical_vector(_fit_model.unpack(v, lay), lay))(u)
    var = jnp.sum((Jp @ cov) * Jp, axis=1)
    # Unknown, not "perfectly known": a parameter the data do not constrain
    # (its Jacobian column numerically null next to the others, or fewer
    # valid observations than parameters: no noise estimate) or whose
    # variance is not finite or beyond any meaningful range gets sigma = inf.
    null_u = (jnp.diagonal(jtj) <= 1e-10 * (jnp.trace(jtj) / k)) | (n_weight <= k)
    unknown = (jnp.abs(Jp) @ null_u.astype(u.dtype) > 0) | ~jnp.isfinite(var) | (var > 1e6) | (n_weight <= k)
    sigma = jnp.where(unknown, jnp.inf, jnp.sqrt(jnp.clip(jnp.where(unknown, 0.0, var), 0.0, None)))
    return u, code, sol.stats["num_steps"], sigma, final


# eqx.filter_jit: the solver object's array leaves (GaussNewton's learning
# rate) are traced and the rest is static (hashed), like ``lay``, ``max_steps``
# and ``cauchy``; so one compilation per (rung, solver, shapes).
@eqx.filter_jit
def _solve_chunk(u0, obs, w, h, wi, wo, irr, *, lay, solver, max_steps, cauchy):
    """``max_steps`` steps of the Optimistix ``solver`` from u0 for each sample
    of the chunk (vmapped). Returns (u, rms, code, steps, sigma [Pc, k], held-out MSE)."""

    def one(u0, obs, w, h, wi, wo, irr):
        # obs and irr arrive normalised (:func:`_normalise`): radiance per unit
        # irradiance, so the Cauchy scale (relative to the sample's RMS) and its
        # floor (for an all-black sample), the accept test's 1e-30, the ridge's
        # 1e-30 and the solver's atol are in those units, not the capture's.
        sw = jnp.sqrt(w)
        scale = jnp.sqrt(jnp.sum(w * obs * obs) / jnp.maximum(jnp.sum(w), 1.0))
        c = None if cauchy is None else cauchy * scale + 1e-12
        # Component-major [3, N] for the model (it vectorises over the lights).
        obs, sw, h, wi, wo, irr = (x.T for x in (obs, sw, h, wi, wo, irr))
        w2 = sw * sw
        u, code, nsteps, sigma, (_, _, pred) = solve_one(
            lambda u: _fit_model.residual_and_jacobian(u, obs, sw, wi, wo, irr, lay, c), u0, jnp.sum(w2), obs.size,
            lay, solver, max_steps)
        raw = pred - obs
        rms = jnp.sqrt(jnp.sum(w2 * raw * raw) / jnp.maximum(jnp.sum(w2), 1.0))
        hmse = jnp.sum(h * raw * raw) / jnp.maximum(jnp.sum(h), 1.0)
        return u, rms, code, nsteps, sigma, hmse

    return jax.vmap(one)(u0, obs, w, h, wi, wo, irr)


def _union_index(lay: Layout) -> list[int]:
    """Where each of a rung's physical parameters goes in PARAM_NAMES."""
    idx = [0, 1, 2]
    if lay.model >= BLINN_PHONG:
        idx += [3, 4]
    if lay.model >= GGX_ANISO:
        idx += [5, 6]
    if lay.normals:
        idx += [7, 8]
    return idx


def _chunk_size(P: int, chunk: int) -> int:
    """Samples per solver call: ``chunk``, or for fewer samples the next power of two."""
    return chunk if P >= chunk else 1 << max(int(P - 1).bit_length(), 3)


def _chunks_of(index, size):
    """Chunks of ``index``, each padded (repeating its last entry) to ``size``:
    one shape for every call of a fit (straggler rounds and ladder subsets
    included), so the solver compiles once per rung."""
    for s in range(0, len(index), size):
        idx = index[s:s + size]
        n = len(idx)
        if n < size:
            idx = np.concatenate([idx, np.full(size - n, idx[-1])])
        yield idx, n


def _fit_rung(data, w, h, index, lay, u0, opts, bar):
    """Fit one rung to the samples ``index`` (of the block ``data``); returns
    per-sample arrays over ``index`` (:func:`run_rounds`)."""
    obs, _, wi, wo, irr = data
    return run_rounds(
        (obs, w, h, wi, wo, irr), index, lay, u0,
        lambda a: _start_chunk(a[0], a[1], a[3], a[4], a[5], lay),
        lambda u, a: _solve_chunk(u, *a, lay=lay, solver=opts["solver"], max_steps=opts["steps_per_round"],
                                  cauchy=opts["cauchy"]),
        opts, bar)


def run_rounds(arrays, index, lay, u0, start, solve, opts, bar):
    """The rounds of a rung's solve over the samples ``index`` of ``arrays``
    (per-sample NumPy arrays, sample axis first), shared by :func:`fit` and
    :func:`relight.fitting.fit_patterns`: ``opts["size"]`` samples per call
    (padded: one compilation), each round only the samples still at
    ``max_steps`` (straggler compaction), ``opts["rounds"]`` rounds.
    ``start(chunk arrays) -> u [size, k]`` when ``u0`` is None;
    ``solve(u, chunk arrays) -> (u, rms, code, steps, sigma, held-out MSE)``.
    Counts the samples finished on ``bar`` (a ``stage.Phase``). Every chunk
    goes to the devices through ``opts["put"]`` (:func:`_placer`)."""
    dtype = arrays[0].dtype
    chunk = opts["size"]
    put = opts["put"]
    n_all = len(index)
    local = np.arange(n_all)
    take = lambda idx: tuple(put(x[index[idx]]) for x in arrays)  # noqa: E731
    if u0 is None:
        u = np.zeros((n_all, lay.size), dtype)
        for idx, n in _chunks_of(local, chunk):
            u[idx[:n]] = np.asarray(start(take(idx)))[:n]
    else:
        u = np.array(u0, dtype)
    rms = np.zeros(n_all, dtype)
    hmse = np.zeros(n_all, dtype)
    code = np.zeros(n_all, np.int32)
    steps = np.zeros(n_all, np.int32)
    sigma = np.zeros((n_all, len(_fit_model.physical_vector(_fit_model.unpack(jnp.zeros(lay.size), lay), lay))),
                     dtype)
    active = local
    for _ in range(opts["rounds"]):
        for idx, n in _chunks_of(active, chunk):
            out = solve(put(u[idx]), take(idx))
            uu, rr, cc, kk, ss, hh = (np.asarray(x)[:n] for x in out)
            sel = idx[:n]
            u[sel], rms[sel], code[sel], steps[sel], sigma[sel], hmse[sel] = uu, rr, cc, steps[sel] + kk, ss, hh
            bar.advance(int(np.sum(cc != _MAX_STEPS_CODE)))
        active = active[code[active] == _MAX_STEPS_CODE]
        if len(active) == 0:
            break
    if len(active):
        bar.advance(len(active))
    return dict(u=u, rms=rms, hmse=hmse, code=code, steps=steps, sigma=sigma)


@jax.jit(static_argnames=("lay",))
def _physical_chunk(u, lay):
    p = jax.vmap(lambda v: _fit_model.unpack(v, lay))(u)
    return p, jax.vmap(_fit_model.frame)(p["normal"], p["phi"])


def _physical(u, lay, size):
    """A rung's u [n, lay.size] unpacked to NumPy physical maps and the fitted frames R [n, 3, 3]
    (surface-frame coordinates), ``size`` samples per call (padded: one program per rung)."""
    parts = [_physical_chunk(jnp.asarray(u[idx]), lay) for idx, _ in _chunks_of(np.arange(len(u)), size)]
    p, R = jax.tree_util.tree_map(lambda *x: np.concatenate([np.asarray(a) for a in x])[:len(u)], *parts)
    return p, R


def _rungs(model) -> tuple[int, ...]:
    if model == "auto":
        return (LAMBERT, BLINN_PHONG, GGX, GGX_ANISO)
    if model not in MODELS or model == "subsurface":
        raise ValueError(f"fit: model must be 'auto' or one of {MODELS[:SUBSURFACE]} (subsurface: "
                         f"relight.fit_subsurface after a fit), got {model!r}")
    return (MODELS.index(model),)


# ------------------------------------------------------------------ capture sources
# fit reads a capture one block of samples at a time from any of: a stage.Capture (radiance / mask sliced);
# an object with read(views=, lights=, samples=) -> (radiance, mask) (relight.io.CaptureStore), optionally
# read_mask(samples=) for the counting pass; an object with load(samples=) -> .radiance / .valid
# (relight.io.CaptureReader, a capture folder). Each needs shape (V, L, P, C) and rig / cameras as stage
# objects or stage_rig() / stage_cameras() methods returning them.

def _source_kind(capture) -> str:
    """Which of the protocols above ``capture`` follows; TypeError naming ``capture`` if none."""
    if hasattr(capture, "radiance") and hasattr(capture, "mask"):
        return "arrays"
    if callable(getattr(capture, "read", None)) and hasattr(capture, "shape"):
        return "read"
    if callable(getattr(capture, "load", None)) and hasattr(capture, "shape"):
        return "load"
    raise TypeError("fit: capture must be a stage.Capture or a capture source: shape (V, L, P, C) and "
                    "read(views=, lights=, samples=) -> (radiance, mask) (relight.io.open_capture_store) or "
                    f"load(samples=) (relight.io.open_capture), got {type(capture).__name__}")


def _rig_and_cameras(capture):
    """The capture's ``stage.Rig`` and ``stage.Camera`` s (a source's stage_rig() / stage_cameras())."""
    rig = capture.stage_rig() if callable(getattr(capture, "stage_rig", None)) else capture.rig
    cams = capture.stage_cameras() if callable(getattr(capture, "stage_cameras", None)) else capture.cameras
    return rig, tuple(cams)


def _read_samples(capture, kind, s, e):
    """(radiance [V, L, e - s, C], mask [V, L, e - s] bool) of samples s..e, as NumPy."""
    if kind == "arrays":
        return np.asarray(capture.radiance[:, :, s:e]), np.asarray(capture.mask[:, :, s:e], bool)
    if kind == "read":
        rad, mask = capture.read(samples=slice(s, e))
        return np.asarray(rad), np.asarray(mask, bool)
    data = capture.load(samples=slice(s, e))
    rad = np.asarray(data.radiance)
    # A capture folder without a 'valid' channel marks every observation valid (as load_texel_capture does).
    mask = np.ones(rad.shape[:3], bool) if data.valid is None else np.asarray(data.valid, bool)
    return rad, mask


def _read_mask(capture, kind, s, e):
    """The mask [V, L, e - s] of samples s..e, without the radiance where the source can."""
    if kind == "arrays":
        return np.asarray(capture.mask[:, :, s:e], bool)
    if callable(getattr(capture, "read_mask", None)):
        return np.asarray(capture.read_mask(samples=slice(s, e)), bool)
    return _read_samples(capture, kind, s, e)[1]


def _valid_counts(capture, kind, P, step):
    """Valid observations per sample [P] (views x lights), one block of ``step`` samples at a time."""
    out = np.zeros(P, np.int64)
    for s in range(0, P, step):
        e = min(s + step, P)
        out[s:e] = np.sum(_read_mask(capture, kind, s, e), axis=(0, 1))
    return out


# ------------------------------------------------------------------ devices

def _fit_devices(devices) -> list:
    """The devices a fit runs on: None = every local device (``jax.local_devices()``),
    an int n = the first n of them, or a sequence of devices. ValueError naming ``devices``."""
    local = jax.local_devices()
    if devices is None:
        return list(local)
    if isinstance(devices, (int, np.integer)) and not isinstance(devices, bool):
        if not 1 <= int(devices) <= len(local):
            raise ValueError(f"fit: devices must be between 1 and the {len(local)} local device(s), got {devices}")
        return list(local[:int(devices)])
    try:
        devs = list(devices)
    except TypeError:
        raise ValueError(f"fit: devices must be None, an int or a sequence of jax devices, got {devices!r}") from None
    if not devs or not all(isinstance(d, jax.Device) for d in devs) or len(set(devs)) != len(devs):
        raise ValueError(f"fit: devices must be a non-empty sequence of distinct jax devices, got {devices!r}")
    return devs


def _placer(devs):
    """``put(x)``: a NumPy chunk [n, ...] as a jax array on ``devs``. One device: that device (the
    default device's is today's ``jnp.asarray``). Several: the sample axis split over a 1-D
    ``Mesh(devs, ("samples",))`` (``NamedSharding(mesh, PartitionSpec("samples"))``, the rest
    replicated), so the jitted vmapped solve runs data-parallel: no sample talks to another, and the
    partitioner only adds an all-reduce for the batched while loop's "any sample still running"."""
    if len(devs) == 1:
        if devs[0] == jax.devices()[0]:
            return jnp.asarray
        return lambda x: jax.device_put(x, devs[0])
    mesh = jax.sharding.Mesh(np.asarray(devs, dtype=object), ("samples",))
    sharding = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("samples"))
    return lambda x: jax.device_put(x, sharding)


class _Phases:
    """One progress counter per phase name for the whole fit, made at first use, so a phase
    spans every block (``stage.Phase``; its total may be set later, when known)."""

    def __init__(self, progress):
        self.progress, self.bars = progress, {}

    def __call__(self, name: str, total: int | None) -> stage.Phase:
        bar = self.bars.get(name)
        if bar is None:
            bar = self.bars[name] = stage.Phase(self.progress, name, total)
        else:
            bar.total = total
        return bar

    def finish(self, name: str, total: int) -> None:
        """Report ``name``'s total if the blocks that ran it did not know it yet."""
        bar = self.bars.get(name)
        if bar is not None and bar.total is None:
            bar.total = total
            bar.advance(0)


# The Fit's per-sample fields fit assembles (and on_block receives), with their trailing shape and kind.
_FIELDS = dict(rho_d=((3,), "f"), rho_s=((1,), "f"), alpha=((2,), "f"), normal=((3,), "f"), tangent=((3,), "f"),
               model=((), "i"), residual=((), "f"), heldout=((), "f"), result=((), "i"), steps=((), "i"),
               observed=((), "o"), uncertainty=((9,), "f"))


def fit(capture, surface: stage.Surface, *, model: str = "ggx", normals: bool = False,
        solver="lm", loss: str = "cauchy", cauchy: float = 0.1, alpha_floor: float | None = None,
        holdout: int = 5, chunk: int = 64, steps_per_round: int = 20, rounds: int = 3, rtol: float | None = None,
        atol: float | None = None, progress=None, block: int = 4096, devices=None, on_block=None) -> Fit:
    """Fit a reflectance model per sample to an OLAT capture.

    ``capture``: a ``stage.Capture``, or a capture source read ``block``
    samples at a time, never whole: any object with ``shape`` (V, L, P, C),
    ``rig`` / ``cameras`` as stage objects or ``stage_rig()`` /
    ``stage_cameras()`` methods, and either ``read(views=, lights=,
    samples=slice) -> (radiance [V, L, n, C], mask [V, L, n])`` (a
    ``relight.io.open_capture_store`` store; an optional
    ``read_mask(samples=)`` spares the counting pass the radiance) or
    ``load(samples=slice)`` returning ``.radiance`` / ``.valid`` (a
    ``relight.io.open_capture`` folder; no valid channel = all valid).
    Sample p of the capture is sample p of ``surface``.

    ``model``: a rung of ``relight.MODELS`` ("lambert", "blinn_phong", "ggx",
    "ggx_aniso") or "auto" (the ladder: every rung is fitted on all but every
    ``holdout``-th light, scored on those, and each sample keeps the simplest
    rung whose held-out mean squared error is within two standard errors of
    the noise of the best; then it is refitted on every light). ``normals``:
    also fit the shading normal (photometric-stereo start). ``solver``: an
    Optimistix least-squares solver or minimiser object
    (``optx.LevenbergMarquardt(rtol, atol)``, ``optx.GaussNewton``,
    ``optx.Dogleg``, ``optx.BFGS``, ...), used as it is; or one of the names
    ``SOLVERS``: "lm" (Levenberg-Marquardt, default), "gn" (Gauss-Newton),
    "dogleg", "bfgs", which stand for those solvers with tolerances ``rtol`` /
    ``atol`` (default 1e-5 / 1e-6) and, for the first three, the
    normal-equations Cholesky linear solver (``lx.Normal(lx.Cholesky())``);
    ``rtol`` / ``atol`` are for names only. ``Fit.solver`` records the name.
    The solver sees each sample's radiance and irradiance divided by its RMS
    irradiance (docs/fit.md, "Units and scale"), so ``atol`` applies to
    residuals in radiance per unit irradiance (the scale of f_r cos, ~albedo
    / pi), whatever the capture's and rig's units: the fit is invariant under
    a change of units (rig intensities and radiance x k).
    ``loss``: "cauchy" (scale ``cauchy`` x the sample's RMS radiance) or "l2".
    ``alpha_floor``: smallest roughness; default :func:`rig_alpha_floor`.

    Memory (docs/fit.md, "Memory and devices"): samples are read, turned
    into observations, fitted (every rung, the ladder's choice included:
    all of it is per sample) and freed ``block`` at a time, so the working
    set is set by ``block`` (about 40 KiB per sample of a block), not by P;
    the result is a few floats per sample. Any ``block`` gives the same fit
    (``block >= P`` is one block: the whole capture at once).
    Within a block, samples are solved ``chunk`` at a time (``jax.vmap`` over
    the chunk; every call has the same shape, so each rung compiles once per
    fit), so solver memory is bounded by the chunk (a vmapped solve runs until
    its slowest sample stops, so small chunks waste fewer steps; 64-256
    measured best on 2 CPU cores, ``scripts/bench_fit.py``); each sample gets
    up to ``rounds * steps_per_round`` steps, later rounds only for samples
    still unconverged (compacted within the block). ``devices``: None = every
    local device (``jax.local_devices()``), an int n = the first n, or a
    sequence of devices; with several, each chunk (rounded up to a multiple
    of their number) has its sample axis split over them
    (``NamedSharding`` on a 1-D ``Mesh`` named "samples"): data-parallel.
    ``on_block(start, stop, arrays)``, if given, is called after each block
    with ``arrays`` a dict of NumPy arrays over samples start..stop, the
    Fit's per-sample fields as they will be in the result (rho_d, rho_s,
    alpha, normal, tangent, model, residual, heldout, result, steps,
    observed, uncertainty): to write results as they are produced.

    ``progress(phase, done, total)`` (``stage.Progress``) reports finished
    samples per pass over all blocks: phase "fit <rung>" (``model="auto"``:
    "fit <rung> (held out)" for each rung's trial, total P, and "fit <rung>"
    for each refit, its total the samples that chose the rung: None until
    the last block is decided), ``done`` of ``total`` samples; with several
    blocks the phases take turns, block by block. NaN never leaves: a sample
    with too few observations gets grey defaults, and one whose solve fails
    keeps its start; both are flagged in ``Fit.failed``.
    """
    kind = _source_kind(capture)
    V, L, P, C = (int(s) for s in capture.shape)
    _check_fit_args(P, C, surface, chunk, rounds, steps_per_round, block, progress, on_block, loss, cauchy, model,
                    holdout)
    solver, solver_name = resolve_solver(solver, rtol, atol)
    rungs = _rungs(model)
    rig, cameras = _rig_and_cameras(capture)
    if len(cameras) != V:
        raise ValueError(f"fit: capture has {V} views but {len(cameras)} cameras")
    floor = rig_alpha_floor(rig) if alpha_floor is None else float(alpha_floor)
    if not 0 < floor < 1:
        raise ValueError(f"fit: alpha_floor must be in (0, 1), got {floor}")
    devs = _fit_devices(devices)
    block = int(block)
    # Optimistix's LM mixes its damping dtype with JAX's default float, so
    # compute in that (float32 unless jax_enable_x64 is on).
    dt = np.dtype(jnp.result_type(float))
    # One observation count for every chunk of every block (the largest any
    # sample has, rounded up) so the solver compiles once: a pass over the mask only.
    n_valid = _valid_counts(capture, kind, P, block)
    n_keep, opts = _solve_plan(P, n_valid, chunk, devs, rounds, steps_per_round, solver, loss, cauchy)
    kinds = {"f": dt, "i": np.int32, "o": np.float32}
    out = {k: np.zeros((P, *shape), kinds[c]) for k, (shape, c) in _FIELDS.items()}
    phases = _Phases(progress)
    chosen = dict.fromkeys(rungs, 0)
    for b0 in range(0, P, block):
        b1 = min(b0 + block, P)
        part = _fit_block(capture, kind, rig, cameras, surface, b0, b1, n_valid[b0:b1], n_keep, dt, rungs, normals,
                          floor, holdout, chunk, opts, phases, chosen, last=b1 == P)
        for k, v in part.items():
            out[k][b0:b1] = v
        if on_block is not None:
            on_block(b0, b1, part)
    # A refit phase whose rung the last block did not use learns its total only now.
    for k in rungs if len(rungs) > 1 else ():
        phases.finish(f"fit {MODELS[k]}", chosen[k])
    return fit_from_arrays(out, dt, floor, solver_name)


def _solve_plan(P, n_valid, chunk, devs, rounds, steps_per_round, solver, loss, cauchy):
    """(n_keep, opts): the packed observation count (the most any sample has,
    rounded up to a bucket of :func:`_obs_bucket`) and the solver options with one padded chunk shape for
    the whole fit (P, not the block, sets it; a multiple of the devices), so
    every block and every process compiles the same programs."""
    n_keep = _obs_bucket(int(np.max(n_valid)))
    size = -(-_chunk_size(P, chunk) // len(devs)) * len(devs)
    opts = dict(size=size, rounds=rounds, steps_per_round=steps_per_round, solver=solver, put=_placer(devs),
                cauchy=float(cauchy) if loss == "cauchy" else None)
    return n_keep, opts


def _obs_bucket(n: int) -> int:
    """The padded observation count for a capture whose richest sample has ``n``: the smallest of 32,
    64, 96, 128, 192, 256, 384, 512, 768, ... (multiples of 32 up to 128, then 1 or 1.5 times a power of
    two) that holds it. Coarse buckets let captures of other sizes and coverage reuse the compiled
    solver (each rung's program is specialised to this count); the padding (w = 0) costs at most a third
    more work per step beyond 128 observations."""
    n = max(int(n), 1)
    if n <= 128:
        return -(-n // 32) * 32
    b = 128
    while b < n:
        b = b * 3 // 2 if (b & (b - 1)) == 0 else b * 4 // 3
    return b


def fit_from_arrays(out: dict, dt, floor: float, solver_name: str, min_observed: int = _MIN_OBSERVATIONS) -> Fit:
    """A ``Fit`` from its per-sample NumPy arrays (the ``on_block`` fields, [P, ...])."""
    f = lambda x: jnp.asarray(x, dt)  # noqa: E731
    i32 = lambda x: jnp.asarray(x, jnp.int32)  # noqa: E731
    return Fit(rho_d=f(out["rho_d"]), rho_s=f(out["rho_s"]), alpha=f(out["alpha"]), normal=f(out["normal"]),
               tangent=f(out["tangent"]), model=i32(out["model"]), residual=f(out["residual"]),
               heldout=f(out["heldout"]), result=i32(out["result"]), steps=i32(out["steps"]),
               observed=jnp.asarray(out["observed"], jnp.float32), uncertainty=f(out["uncertainty"]),
               alpha_floor=floor, solver=solver_name, min_observed=int(min_observed))


def _check_fit_args(P, C, surface, chunk, rounds, steps_per_round, block, progress, on_block, loss, cauchy, model,
                    holdout) -> None:
    """fit's argument checks: ValueError / TypeError naming the argument."""
    if surface.num_samples != P:
        raise ValueError(f"fit: capture has {P} samples but the surface has {surface.num_samples}")
    if C != 3:
        raise ValueError(f"fit: expects RGB radiance (C = 3), got C = {C}")
    if chunk < 1 or rounds < 1 or steps_per_round < 1:
        raise ValueError("fit: chunk, rounds and steps_per_round must be >= 1")
    if isinstance(block, bool) or not isinstance(block, (int, np.integer)) or block < 1:
        raise ValueError(f"fit: block must be an int >= 1 (samples per block), got {block!r}")
    if progress is not None and not callable(progress):
        raise TypeError(f"fit: progress must be a callable progress(phase, done, total) or None, got {progress!r}")
    if on_block is not None and not callable(on_block):
        raise TypeError(f"fit: on_block must be a callable on_block(start, stop, arrays) or None, got {on_block!r}")
    if loss not in LOSSES:
        raise ValueError(f"fit: loss must be one of {LOSSES}, got {loss!r}")
    if loss == "cauchy" and not cauchy > 0:
        raise ValueError(f"fit: the Cauchy scale must be > 0, got {cauchy}")
    if model == "auto" and holdout < 2:
        raise ValueError(f"fit: holdout must be >= 2 (every holdout-th light is held out), got {holdout}")


def _fit_block(capture, kind, rig, cameras, surface, b0, b1, n_valid, n_keep, dt, rungs, normals, floor, holdout,
               chunk, opts, phases, chosen, last):
    """Every rung (and the ladder's choice) for samples b0..b1: the Fit's per-sample fields as NumPy
    arrays [b1 - b0, ...] (``_FIELDS``). The block's observations live only in here."""
    n = b1 - b0
    rad, mask = _read_samples(capture, kind, b0, b1)
    # Every chunk padded to ``chunk`` samples (repeating its last): the shading geometry's programs
    # compile for one shape, whatever the block or capture size.
    parts = []
    for s in range(0, n, chunk):
        idx, m = next(_chunks_of(np.arange(s, min(s + chunk, n)), chunk))
        part = _observations_of(rad[:, :, idx], mask[:, :, idx], rig, cameras, _rows(surface, b0 + idx), n_keep,
                                dt)
        parts.append(tuple(x[:m] for x in part))
    del rad, mask
    obs, w, wi, wo, irr, light = (np.concatenate(x) for x in zip(*parts, strict=True))
    del parts
    # The solver sees radiance per unit irradiance (docs/fit.md, "Units and scale").
    obs, irr, unit = _normalise(obs, w, irr)
    data = (obs, w, wi, wo, irr)
    every = np.arange(n)
    zero = np.zeros_like(w)
    block_surface = _rows(surface, np.arange(b0, b1))

    if len(rungs) == 1:
        k = rungs[0]
        choice = np.full(n, k, np.int32)
        bar = phases(f"fit {MODELS[k]}", surface.num_samples)
        fits = {k: (every, _fit_rung(data, w, zero, every, Layout(k, normals, floor), None, opts, bar))}
        heldout = np.zeros(n, dt)
    else:
        hmask = (light % holdout == holdout // 2)[..., None].astype(dt) * w
        train = w - hmask
        trial = {k: _fit_rung(data, train, hmask, every, Layout(k, normals, floor), None, opts,
                              phases(f"fit {MODELS[k]} (held out)", surface.num_samples)) for k in rungs}
        hm = np.stack([trial[k]["hmse"] for k in rungs])  # [K, n]
        n_h = np.maximum(np.sum(hmask[..., 0], axis=1), 1.0)
        best = np.min(hm, axis=0)
        # Noise from the richest rung's training residual; the held-out MSE of
        # n_h Gaussian residuals has a standard error of s^2 sqrt(2 / n_h).
        s2 = np.min(np.stack([trial[k]["rms"] ** 2 for k in rungs]), axis=0)
        tol = 2.0 * s2 * np.sqrt(2.0 / n_h)
        ok = hm <= (best + tol)[None]
        choice = np.asarray(rungs, np.int32)[np.argmax(ok, axis=0)]
        heldout = np.sqrt(hm[np.argmax(ok, axis=0), every]).astype(dt)
        fits = {}
        for k in rungs:
            sel = np.nonzero(choice == k)[0]
            chosen[k] += len(sel)
            if len(sel):
                bar = phases(f"fit {MODELS[k]}", chosen[k] if last else None)
                fits[k] = (sel, _fit_rung(data, w, zero, sel, Layout(k, normals, floor), trial[k]["u"][sel], opts,
                                          bar))
    out = _assemble(fits, choice, n, normals, floor, dt, block_surface, opts["size"])
    return finish_block(out, n_valid, block_surface, unit, heldout, choice, dt, _MIN_OBSERVATIONS)


def finish_block(out, n_valid, block_surface, unit, heldout, choice, dt, min_observed: int) -> dict:
    """A block's Fit fields (``_FIELDS``) from :func:`_assemble`'s ``out``:
    samples with fewer than ``min_observed`` valid observations get grey
    defaults and every parameter of their rung unknown (sigma inf); NaN is
    replaced (parameters 0, sigma inf, residual the largest float); the RMS
    residual and held-out RMS are scaled back by ``unit`` [n] to the
    capture's radiance units. Shared by :func:`fit` and
    :func:`relight.fitting.fit_patterns`."""
    nobs = n_valid.astype(np.float32)
    empty = nobs < min_observed
    # A sample with no usable data gets grey defaults instead of whatever the solver made of zeros.
    out["rho_d"][empty] = 0.5
    out["rho_s"][empty] = 0.04
    out["alpha"][empty] = 0.3
    out["normal"][empty] = np.asarray(block_surface.normal, dt)[empty]
    out["tangent"][empty] = np.asarray(block_surface.tangent, dt)[empty]
    # No usable data: every parameter the sample's rung has is unknown.
    unc = out["uncertainty"]
    unc[empty] = np.where((unc[empty] != 0) | (np.arange(9) < 3), np.inf, 0.0)
    big = np.finfo(np.float32).max
    for k in ("rho_d", "rho_s", "alpha"):
        out[k] = np.nan_to_num(out[k], nan=0.0, posinf=0.0, neginf=0.0)
    out["uncertainty"] = np.nan_to_num(unc, nan=np.inf, posinf=np.inf, neginf=np.inf)
    # Residuals back in the capture's radiance units.
    out["residual"] = np.nan_to_num(out["residual"] * unit.astype(dt), nan=big, posinf=big)
    out["heldout"] = np.nan_to_num(heldout * unit.astype(dt))
    out["model"] = choice
    out["observed"] = nobs
    return {k: out[k] for k in _FIELDS}


def _rows(surface: stage.Surface, index) -> stage.Surface:
    """``surface.subset(index)`` taken on the host (NumPy rows, then device arrays): no gather program
    compiled per index length."""
    index = np.asarray(index)
    return jax.tree_util.tree_map(lambda a: jnp.asarray(np.asarray(a)[index]), surface)


def _assemble(fits, choice, P, normals, floor, dt, surface, size):
    out = dict(rho_d=np.zeros((P, 3), dt), rho_s=np.zeros((P, 1), dt), alpha=np.zeros((P, 2), dt),
               normal=np.zeros((P, 3), dt), tangent=np.zeros((P, 3), dt), residual=np.zeros(P, dt),
               result=np.zeros(P, np.int32), steps=np.zeros(P, np.int32), uncertainty=np.zeros((P, 9), dt))
    T, B, N = (np.asarray(x, np.float64) for x in (surface.tangent, surface.bitangent, surface.normal))
    for k, (sel, r) in fits.items():
        lay = Layout(k, normals, floor)
        p, R = _physical(r["u"], lay, size)
        out["rho_d"][sel] = p["rho_d"]
        out["rho_s"][sel] = p["rho_s"]
        out["alpha"][sel] = p["alpha"]
        # Fitted frame (surface-frame coordinates) to world space.
        R = R.astype(np.float64)
        t_l, n_l = R[:, 0], R[:, 2]
        Ts, Bs, Ns = T[sel], B[sel], N[sel]
        to_world = lambda v, Ts=Ts, Bs=Bs, Ns=Ns: v[:, 0:1] * Ts + v[:, 1:2] * Bs + v[:, 2:3] * Ns  # noqa: E731
        out["normal"][sel] = to_world(n_l)
        out["tangent"][sel] = to_world(t_l)
        out["residual"][sel] = r["rms"]
        out["result"][sel] = r["code"]
        out["steps"][sel] = r["steps"]
        out["uncertainty"][np.ix_(sel, _union_index(lay))] = r["sigma"]
    return out


def _normalise(obs, w, irr):
    """(obs / E, irr / E, E [P]) for each sample's irradiance scale E, the RMS
    of its irradiance at normal incidence over its valid observations (1 for
    a sample without any). Dividing the observations and the irradiance by
    one number leaves every parameter unchanged (the model is linear in the
    irradiance) and makes the solver's problem that of a rig of irradiance
    ~1: radiance per unit irradiance, the scale of f_r cos (albedo / pi), in
    any capture or rig units. So Optimistix's ``atol``, its initial damping,
    the Cauchy scale's floor, the accept test and the start's floors are
    relative, not in the capture's units; a change of units (rig and radiance
    x k) is an exact symmetry of the normalised problem. For distant lights
    of irradiance 1 (``stage.geodesic_dome()``) E is exactly 1."""
    wv = w[..., 0].astype(np.float64)
    i2 = np.sum(wv[..., None] * np.square(irr, dtype=np.float64), axis=(1, 2))
    n = irr.shape[-1] * np.sum(wv, axis=1)
    unit = np.sqrt(np.where(n > 0, i2 / np.maximum(n, 1.0), 1.0))
    unit = np.where(np.isfinite(unit) & (unit > 0), unit, 1.0)
    inv = (1.0 / unit)[:, None, None]
    return (obs * inv).astype(obs.dtype), (irr * inv).astype(irr.dtype), unit


def _observations(capture, surface, s, e, n_keep, dt):
    """Per-sample observation arrays [e - s, n_keep, ...] for samples s..e of
    ``capture`` (a stage.Capture or a source, as :func:`fit` takes):
    radiance, weights (1 valid / 0 padding), wi, wo (local), irradiance and
    the light index of each observation."""
    kind = _source_kind(capture)
    rad, mask = _read_samples(capture, kind, s, e)
    rig, cameras = _rig_and_cameras(capture)
    return _observations_of(rad, mask, rig, cameras, surface.subset(np.arange(s, e)), n_keep, dt)


def _observations_of(radiance, mask, rig, cameras, sub, n_keep, dt):
    """:func:`_observations` of samples already read: ``radiance`` [V, L, n, C], ``mask`` [V, L, n]
    and their surface ``sub`` (n samples)."""
    n = sub.num_samples
    obs_v, w_v, wi_v, wo_v, irr_v, li_v = [], [], [], [], [], []
    L = rig.num_lights
    for v, cam in enumerate(cameras):
        wi, wo, irr = stage.shading_directions(sub, rig, cam)
        obs_v.append(np.swapaxes(np.asarray(radiance[v], np.float32), 0, 1))
        w_v.append(np.swapaxes(np.asarray(mask[v]), 0, 1))
        wi_v.append(np.swapaxes(np.asarray(wi), 0, 1))
        wo_v.append(np.broadcast_to(np.asarray(wo)[:, None], wi_v[-1].shape))
        irr_v.append(np.swapaxes(np.asarray(irr), 0, 1))
        li_v.append(np.broadcast_to(np.arange(L)[None], (n, L)))
    cat = lambda xs: np.concatenate(xs, axis=1)  # noqa: E731  [n, V*L, ...]
    obs, wmask, wi, wo, irr, li = cat(obs_v), cat(w_v), cat(wi_v), cat(wo_v), cat(irr_v), cat(li_v)
    # Keep only valid observations (valid first, then padding): typically
    # half of a rig's lights are behind a sample.
    order = np.argsort(~wmask, axis=1, kind="stable")[:, :n_keep]
    if order.shape[1] < n_keep:  # fewer observations than the rounded-up count: pad with invalid ones
        order = np.concatenate([order, np.repeat(order[:, -1:], n_keep - order.shape[1], axis=1)], axis=1)
    take = lambda a: np.take_along_axis(a, order.reshape(order.shape + (1,) * (a.ndim - 2)), axis=1)  # noqa: E731
    obs, wm, wi, wo, irr, li = take(obs), take(wmask), take(wi), take(wo), take(irr), take(li)
    wm[:, wmask.shape[1]:] = False  # the repeated padding columns, if any
    w = np.broadcast_to(wm[..., None], obs.shape).astype(dt)
    return obs.astype(dt), w, wi.astype(dt), wo.astype(dt), irr.astype(dt), li

"""The solvers of a fit: the string spellings of ``fit(solver=...)`` and one sample's solve.

``resolve_solver`` turns ``fit``'s ``solver`` argument (a name of ``SOLVERS`` or an Optimistix
least-squares solver or minimiser object) into the Optimistix solver; :func:`solve_one` runs it on one
sample's structured residual with the fitter's accept test and one-sigma uncertainties;
``_solve_chunk`` / ``_start_chunk`` are those vmapped over a chunk of samples (compiled once per rung,
solver and shape).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx

from . import _init as _fit_init
from . import _model as _fit_model
from ._lm import NormalLevenbergMarquardt
from ._model import BLINN_PHONG, Layout
from ._result import RESULTS, Fit, result_code
from ._spd import SPDCholesky, spd_inverse

# The string spellings of ``fit(solver=...)`` (the CLI's --solver) and their
# tolerances. Normal equations + Cholesky: the systems are 3-9 wide and, with
# LM's damping, well conditioned; several times cheaper than QR of [N, p].
_RTOL, _ATOL = 1e-5, 1e-6
_CHOLESKY = lx.Normal(SPDCholesky())
# name -> the Optimistix solver it stands for, built with (rtol, atol).
_NAMED = {
    "lm": lambda rtol, atol: NormalLevenbergMarquardt(rtol=rtol, atol=atol),
    "optx-lm": lambda rtol, atol: optx.LevenbergMarquardt(rtol=rtol, atol=atol, linear_solver=_CHOLESKY),
    "gn": lambda rtol, atol: optx.GaussNewton(rtol=rtol, atol=atol, linear_solver=_CHOLESKY),
    "dogleg": lambda rtol, atol: optx.Dogleg(rtol=rtol, atol=atol, linear_solver=_CHOLESKY),
    "bfgs": lambda rtol, atol: optx.BFGS(rtol=rtol, atol=atol),
}
SOLVERS = tuple(_NAMED)


def _solver_name(solver) -> str:
    """A short name of an Optimistix solver object for reports: its class and tolerances."""
    tol = ", ".join(f"{k}={getattr(solver, k):g}" for k in ("rtol", "atol")
                    if isinstance(getattr(solver, k, None), (int, float)))
    return f"{type(solver).__name__}({tol})"


def resolve_solver(solver, rtol: float | None = None, atol: float | None = None):
    """The Optimistix solver and its name for ``fit``'s ``solver`` argument.

    Args:
        solver: a string of ``SOLVERS`` (built with ``rtol`` / ``atol`` and, but for "bfgs", the
            normal-equations Cholesky linear solver) or an Optimistix least-squares solver or minimiser
            object, used as it is (it carries its own tolerances).
        rtol, atol: for a name only (default 1e-5 / 1e-6); must be None with a solver object.

    Returns:
        (solver, name): the name is the string, or the object's class and tolerances.

    Raises ValueError / TypeError naming ``solver`` otherwise.
    """
    if isinstance(solver, str):
        if solver not in _NAMED:
            raise ValueError(f"fit: solver must be one of {SOLVERS} or an Optimistix solver object, got {solver!r}")
        rtol = _RTOL if rtol is None else float(rtol)
        atol = _ATOL if atol is None else float(atol)
        if not (rtol >= 0 and atol >= 0):
            raise ValueError(f"fit: rtol and atol must be >= 0, got rtol={rtol}, atol={atol}")
        return _NAMED[solver](rtol, atol), solver
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


_LOBE = ("rho_s", "alpha_x", "alpha_y", "phi")


def held_lobe(u, lay: Layout):
    """[size] bool: the entries of u that are a switched-off lobe's (F0 below ``Fit.COLLAPSED_F0``: the
    lobe adds nothing, its F0 sits at its bound and its roughness is free), all False for Lambert. A lobe
    collapsed the other way, roughness at ``Fit.COLLAPSED_ALPHA`` with F0 on, is broad and grey and may
    have taken part of the diffuse signal: it stays in the covariance, where that trade shows as the
    albedo's sigma (``Fit.ambiguous``)."""
    lobe = jnp.asarray([name in _LOBE for name in lay.names])
    if lay.model < BLINN_PHONG:
        return lobe
    p = _fit_model.unpack(u, lay)
    return lobe & (p["rho_s"][0] < Fit.COLLAPSED_F0)


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
    the start, code ``RESULTS.rejected``). Returns (u, code, steps, sigma [k'] of
    the physical parameters (:func:`relight.fitting._model.physical_vector`),
    rj(u))."""
    normal_lm = isinstance(solver, NormalLevenbergMarquardt)
    if normal_lm:  # it takes the structured normal equations as fn's aux
        def normal(u, _):
            r, J = rj(u)[:2]
            return r, (J.T @ J, J.T @ r)

        sol = optx.least_squares(normal, solver, u0, has_aux=True, options={"jac": "normal"},
                                 max_steps=max_steps, throw=False)
        # The costs of y0 and of the accepted point, and J^T J there, come from the loop's own
        # evaluations: no further copies of the model in the program (a third less to compile).
        cost0, cost1 = 2 * sol.stats["initial_cost"], 2 * sol.stats["cost"]
    else:
        res = _fit_model.materialised(rj)
        sol = optx.least_squares(lambda u, _: res(u), solver, u0, max_steps=max_steps, throw=False)
        cost0 = jnp.sum(res(u0) ** 2)
        cost1 = jnp.sum(res(sol.value) ** 2)
    u1 = sol.value
    # Reject only a real increase: the slack is 1e-6 plus the worst-case
    # rounding of a sum of n = 3N squares in this dtype, about n eps (Higham
    # 2002, ch. 4). Near the optimum float32 costs differ by that much (LM
    # accepts steps whose predicted reduction is ~0): 1e-6 alone flagged 1-2%
    # of samples rejected in float32 by rounding. float64: unchanged.
    slack = 1e-6 + n_entries * float(jnp.finfo(u0.dtype).eps)
    good = jnp.all(jnp.isfinite(u1)) & jnp.isfinite(cost1) & (cost1 <= cost0 * (1 + slack) + 1e-30)
    u = jnp.where(good, u1, u0)
    code = result_code(RESULTS.where(good, RESULTS.promote(sol.result), RESULTS.rejected))
    final = rj(u)  # with NormalLevenbergMarquardt only its residual and extras are used: J is dead code
    r_u, J = final[:2]
    # A rejected NormalLevenbergMarquardt solve is a non-finite start (it accepts only steps that
    # lower the cost): no curvature to report, every sigma unknown.
    jtj = jnp.where(good, sol.aux[0], 0.0) if normal_lm else J.T @ J
    # One-sigma uncertainties from the Gauss-Newton covariance s^2 (J^T J)^-1
    # of the (robust) residual, mapped to the physical parameters. A switched-off lobe (:func:`held_lobe`)
    # is held where it is, as bounded least squares treats a parameter at an active bound: the covariance
    # is the free parameters' (the rest of J^T J), and the lobe's own sigmas are unknown. Left in, its flat
    # sigmoid columns made the albedo's sigma read as "ambiguous" on texels whose lights show no lobe at
    # all (docs/fit.md, "How", item 6).
    fixed = held_lobe(u, lay)
    free = ~fixed
    k = u.shape[0]
    k_free = jnp.sum(free.astype(u.dtype))
    jtj = jnp.where(free[:, None] & free[None, :], jtj, 0.0)
    dof = jnp.maximum(n_weight - k_free, 1.0)
    s2 = jnp.sum(r_u ** 2) / dof
    ridge = 1e-9 * (jnp.trace(jtj) / jnp.maximum(k_free, 1.0) + 1e-30)
    cov = s2 * spd_inverse(jtj + jnp.diag(jnp.where(fixed, 1.0, ridge)))
    Jp = jax.jacfwd(lambda v: _fit_model.physical_vector(_fit_model.unpack(v, lay), lay))(u)
    var = jnp.sum((Jp @ cov) * Jp, axis=1)
    # Unknown, not "perfectly known": a parameter the data do not constrain
    # (its Jacobian column numerically null next to the others, or fewer
    # valid observations than parameters: no noise estimate) or whose
    # variance is not finite or beyond any meaningful range gets sigma = inf.
    null_u = (jnp.diagonal(jtj) <= 1e-10 * (jnp.trace(jtj) / k)) | (n_weight <= k) | fixed
    # (physical_vector lists the parameters in u's order, so ``fixed`` marks the held lobe's there too:
    # its sigmas are unknown even where a saturated sigmoid zeroes their Jacobian rows.)
    unknown = ((jnp.abs(Jp) @ null_u.astype(u.dtype) > 0) | ~jnp.isfinite(var) | (var > 1e6) | (n_weight <= k)
               | fixed)
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

"""Levenberg-Marquardt as an Optimistix least-squares solver with one model
evaluation per step, for small dense problems (a texel's 3-9 parameters).

``optimistix.LevenbergMarquardt`` keeps the Jacobian as a linear function and
re-materialises it, and its trust-region bookkeeping, every step; vmapped over
a chunk of texels both branches of each ``lax.cond`` run. That costs about as
much again as the model evaluation itself (``scripts/profile_fit_step.py``).
Here a step is: evaluate the residual r and the Jacobian J at the trial point
(one ``jax.linearize``; the residuals of ``relight.fitting._model`` carry their
structured Jacobian, so this is one model evaluation), accept or reject it by
the gain ratio, and propose the next trial from the normal equations
(J^T J + mu D) delta = -J^T r with a p x p Cholesky. A rejected trial costs no
extra evaluation: the accepted point's J^T J and J^T r are kept in the state.

Damping: Marquardt's scaling D = diag(J^T J) (invariant to each parameter's
units; Marquardt 1963, More 1978) and Nielsen's update of mu from the gain
ratio rho (Nielsen 1999; Madsen, Nielsen & Tingleff 2004, "Methods for
non-linear least squares problems", Algorithm 3.16). Stops, as Optimistix's
Gauss-Newton family does, when an accepted step is small in both y and the
cost (``optimistix.cauchy_termination``'s rule with ``rtol`` / ``atol``), when
the undamped Gauss-Newton step is below the y tolerance or promises less than
``rtol`` of the cost (plus ``atol``^2: so ``rtol`` bounds the relative cost
left, and y is then within about sqrt(rtol) of the minimum in units of its
uncertainty), or when even a step below the y tolerance fails to lower the
cost (converged to rounding).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, Bool, Float, Int

from ._spd import spd_solve

# Nielsen's initial damping relative to Marquardt's scaling (MNT 2004 suggest
# tau = 1e-3 when the start is believed good; the photometric start is).
_TAU = 1e-3


class _State(eqx.Module):
    y_eval: Float[Array, " p"]  # the trial point the next step evaluates
    first: Bool[Array, ""]
    cost: Float[Array, ""]  # 0.5 |r|^2 at the accepted point
    cost0: Float[Array, ""]  # 0.5 |r|^2 at y0 (the first evaluation)
    jtj: Float[Array, "p p"]
    grad: Float[Array, " p"]  # J^T r at the accepted point
    pred: Float[Array, ""]  # the model's predicted cost reduction for y_eval
    mu: Float[Array, ""]
    nu: Float[Array, ""]
    terminate: Bool[Array, ""]
    result: optx.RESULTS
    aux: Any
    num_accepted: Int[Array, ""]


class NormalLevenbergMarquardt(optx.AbstractLeastSquaresSolver):
    """Levenberg-Marquardt on the normal equations, one evaluation of the
    residual and its Jacobian per step (see the module docstring); for a
    residual function of a 1-D array ``y`` returning a 1-D array. Use it like
    any Optimistix least-squares solver: ``optimistix.least_squares(fn,
    NormalLevenbergMarquardt(rtol, atol), y0)``.

    ``options={"jac": "normal"}`` with ``has_aux=True``: ``fn`` returns the
    normal equations' (J^T J [p, p], J^T r [p]) of its residual as its aux
    output (from a structured, hand-derived Jacobian), used instead of
    ``jax.linearize`` (whose pass through a ``custom_jvp`` Jacobian costs
    several model evaluations on XLA:CPU) and carried at p x p, not m x p."""

    rtol: float
    atol: float
    norm: Callable = optx.max_norm

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        if not (isinstance(y, jax.Array | jax.ShapeDtypeStruct) or hasattr(y, "shape")) or jnp.ndim(y) != 1:
            raise TypeError(f"NormalLevenbergMarquardt: y must be a 1-D array, got {jax.eval_shape(lambda: y)}")
        if not hasattr(f_struct, "shape") or len(f_struct.shape) != 1:
            raise TypeError(f"NormalLevenbergMarquardt: the residual must be a 1-D array, got {f_struct}")
        p = y.shape[0]
        if options.get("jac", "fwd") == "normal" and [getattr(a, "shape", None) for a in
                                                      jax.tree.leaves(aux_struct)] != [(p, p), (p,)]:
            raise TypeError(f"NormalLevenbergMarquardt: options jac='normal' needs fn's aux to be (J^T J [{p}, {p}], "
                            f"J^T r [{p}]), got {aux_struct}")
        dt = y.dtype
        zero = jnp.zeros((), dt)
        return _State(y_eval=y, first=jnp.array(True), cost=zero, cost0=zero, jtj=jnp.zeros((p, p), dt),
                      grad=jnp.zeros((p,), dt), pred=jnp.ones((), dt), mu=jnp.ones((), dt),
                      nu=jnp.full((), 2.0, dt), terminate=jnp.array(False), result=optx.RESULTS.successful,
                      aux=jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), aux_struct),
                      num_accepted=jnp.array(0))

    def step(self, fn, y, args, options, state: _State, tags):
        dt = y.dtype
        if options.get("jac", "fwd") == "normal":
            r, aux = fn(state.y_eval, args)
            jtj_new, grad_new = aux
        else:
            r, lin, aux = jax.linearize(lambda v: fn(v, args), state.y_eval, has_aux=True)
            jt = jax.vmap(lin)(jnp.eye(y.shape[0], dtype=dt))  # J^T [p, m]
            jtj_new, grad_new = jt @ jt.T, jt @ r
        cost = 0.5 * jnp.sum(r * r)
        finite = jnp.isfinite(cost) & jnp.all(jnp.isfinite(jtj_new)) & jnp.all(jnp.isfinite(grad_new))
        rho = jnp.where(state.pred > 0, (state.cost - cost) / jnp.where(state.pred > 0, state.pred, 1.0), -1.0)
        accept = finite & (state.first | (rho > 0))

        # The cost and step tests on an accepted step (Optimistix's own rule).
        y_diff = state.y_eval - y
        small_y = self.norm(jnp.abs(y_diff) / (self.atol + self.rtol * jnp.abs(y))) < 1
        small_f = jnp.abs(state.cost - cost) < self.atol + self.rtol * jnp.abs(state.cost)
        converged = ~state.first & jnp.where(accept, small_y & small_f, small_y)

        pick = lambda a, b: jnp.where(accept, a, b)  # noqa: E731
        y_new = pick(state.y_eval, y)
        jtj = pick(jtj_new, state.jtj)
        grad = pick(grad_new, state.grad)
        cost_new = pick(cost, state.cost)
        # Nielsen: shrink mu by the gain ratio's cubic on acceptance, grow it
        # geometrically (nu doubling) on rejection.
        shrink = jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
        mu = jnp.where(state.first, jnp.asarray(_TAU, dt), jnp.where(accept, state.mu * shrink, state.mu * state.nu))
        nu = jnp.where(accept, jnp.asarray(2.0, dt), 2.0 * state.nu)

        d = jnp.diagonal(jtj)
        d = jnp.maximum(d, 1e-12 * jnp.max(d) + jnp.finfo(dt).tiny)
        delta = -spd_solve(jtj + jnp.diag(mu * d), grad)
        ok = jnp.all(jnp.isfinite(delta))
        delta = jnp.where(ok, delta, 0.0)
        pred = jnp.where(ok, 0.5 * jnp.dot(delta, mu * d * delta - grad), 0.0)
        # Also converged where the undamped Gauss-Newton step (the distance to
        # the model's minimum) is below the y tolerance, or where it promises
        # less than rtol of the cost (plus atol^2): in a flat valley accepted
        # steps can stay long in y while what is left to gain is far below
        # what the noise resolves (a parameter change is significant at a
        # cost change of about cost / dof, 2e-3 of it for 500 residuals).
        newton = spd_solve(jtj + jnp.diag(1e-9 * d), grad)
        gain = 0.5 * jnp.dot(grad, newton)
        near = self.norm(jnp.abs(newton) / (self.atol + self.rtol * jnp.abs(y_new))) < 1
        left = gain <= self.rtol * cost_new + self.atol ** 2
        flat = accept & ~state.first & jnp.isfinite(gain) & (near | left)
        converged = converged | flat

        bad_start = state.first & ~finite
        result = optx.RESULTS.where(bad_start, optx.RESULTS.nonlinear_divergence, optx.RESULTS.successful)
        new = _State(y_eval=y_new + delta, first=jnp.array(False), cost=cost_new,
                     cost0=jnp.where(state.first, cost, state.cost0), jtj=jtj, grad=grad, pred=pred,
                     mu=mu, nu=nu, terminate=converged | bad_start, result=result,
                     aux=jax.tree.map(lambda a, b: jnp.where(accept, a, b), aux, state.aux),
                     num_accepted=state.num_accepted + accept.astype(state.num_accepted.dtype))
        return y_new, new, new.aux

    def terminate(self, fn, y, args, options, state: _State, tags):
        return state.terminate, state.result

    def postprocess(self, fn, y, aux, args, options, state: _State, tags, result):
        return y, aux, {"num_accepted_steps": state.num_accepted, "cost": state.cost, "initial_cost": state.cost0}


__all__ = ["NormalLevenbergMarquardt"]

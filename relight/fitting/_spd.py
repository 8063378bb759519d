"""Small symmetric positive-definite systems (the fitter's 3 x 3 to 9 x 9 normal equations) solved
with plain array operations: Cholesky (Golub & Van Loan 2013, "Matrix Computations", sec. 4.2)
and the two triangular substitutions, as loops over the static size.

Why not ``jax.scipy.linalg.cho_factor`` / ``jnp.linalg.solve`` / ``lineax.Cholesky``: on the CPU,
under ``jax.vmap`` each is one batched LAPACK custom call that splits the batch over XLA's intra-op
thread pool and waits for its parts from inside a task of that same pool. With every worker of the
pool in such a wait nothing runs the parts: the process sleeps forever (observed with jax 0.10.2 on
2 cores: five of about twelve runs of ``scripts/eval_diligent.py`` stopped at 0% CPU in
``CholeskyFactorization::Kernel``, docs/fit.md, "Findings for the fitter", item 8). Here each step
of a loop is a few elementwise operations over the whole batch. Loops, not unrolled code: unrolled,
the 9 x 9 solves doubled the compile time of a fit's program.

A matrix that is not positive definite gives NaN, as LAPACK's does: the callers test for it.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.flatten_util as jfu
import jax.numpy as jnp
import lineax as lx
from jaxtyping import Array, Float


def cholesky(a: Float[Array, "*batch k k"]) -> Float[Array, "*batch k k"]:
    """The lower Cholesky factor L of a symmetric positive-definite ``a`` (a = L L^T; only a's lower
    triangle is read), one column a loop step (Golub & Van Loan's column form). NaN where ``a`` is not
    positive definite."""
    k = a.shape[-1]
    idx = jnp.arange(k)

    def column(j, L):
        row = L[..., j, :]  # L[j, m], zero for m >= j (not yet filled)
        d = jnp.sqrt(a[..., j, j] - jnp.sum(row * row, -1))
        t = a[..., :, j] - jnp.sum(L * row[..., None, :], -1)  # a[i, j] - sum_m L[i, m] L[j, m]
        col = jnp.where(idx > j, t / d[..., None], jnp.where(idx == j, d[..., None], 0.0))
        return L.at[..., :, j].set(col)

    return jax.lax.fori_loop(0, k, column, jnp.zeros_like(a))


def _cho_solve_columns(factor, b):
    """X with (L L^T) X = B for B [*batch, k, r]: forward, then back substitution, a row a loop step
    (the rows not yet solved are zero, so every sum may run over all k)."""
    k = factor.shape[-1]

    def forward(i, y):
        yi = (b[..., i, :] - jnp.sum(factor[..., i, :, None] * y, -2)) / factor[..., i, i, None]
        return y.at[..., i, :].set(yi)

    def back(step, x):
        i = k - 1 - step
        xi = (y[..., i, :] - jnp.sum(factor[..., :, i, None] * x, -2)) / factor[..., i, i, None]
        return x.at[..., i, :].set(xi)

    y = jax.lax.fori_loop(0, k, forward, jnp.zeros_like(b))
    return jax.lax.fori_loop(0, k, back, jnp.zeros_like(b))


def cho_solve(factor: Float[Array, "*batch k k"], b: Float[Array, "*batch k"]) -> Float[Array, "*batch k"]:
    """x with (L L^T) x = b for the lower factor ``factor`` = L of :func:`cholesky`."""
    return _cho_solve_columns(factor, b[..., None])[..., 0]


def spd_solve(a: Float[Array, "*batch k k"], b: Float[Array, "*batch k"]) -> Float[Array, "*batch k"]:
    """x with a x = b for a symmetric positive-definite ``a`` (:func:`cholesky`, :func:`cho_solve`)."""
    return cho_solve(cholesky(a), b)


def spd_inverse(a: Float[Array, "*batch k k"]) -> Float[Array, "*batch k k"]:
    """a^-1 of a symmetric positive-definite ``a``: every column through one factorisation."""
    return _cho_solve_columns(cholesky(a), jnp.broadcast_to(jnp.eye(a.shape[-1], dtype=a.dtype), a.shape))


class SPDCholesky(lx.AbstractLinearSolver):
    """A lineax linear solver for a positive-definite operator: ``lineax.Cholesky`` with
    :func:`cholesky` and :func:`cho_solve` in place of LAPACK, which can hang a batched (vmapped) solve
    on the CPU (the module docstring says how). Wrap it in ``lineax.Normal`` for least squares, as
    ``lineax.Cholesky``: ``optx.LevenbergMarquardt(rtol, atol, linear_solver=lx.Normal(SPDCholesky()))``.
    Meant for small systems (the loops run over the operator's size); a matrix that is not positive
    definite gives a non-finite solution, which lineax reports as a failed solve."""

    def init(self, operator: lx.AbstractLinearOperator, options: dict[str, Any]):
        del options
        if not lx.is_positive_semidefinite(operator):
            raise ValueError("SPDCholesky: the operator must be tagged positive (semi)definite, "
                             "e.g. through lineax.Normal")
        matrix = operator.as_matrix()
        if matrix.shape[0] != matrix.shape[1]:
            raise ValueError(f"SPDCholesky: the operator must be square, got {matrix.shape}")
        return cholesky(matrix)

    def compute(self, state, vector, options: dict[str, Any]):
        del options
        flat, unflatten = jfu.ravel_pytree(vector)
        return unflatten(cho_solve(state, flat)), lx.RESULTS.successful, {}

    def transpose(self, state, options: dict[str, Any]):
        return state, options  # self-adjoint

    def conj(self, state, options: dict[str, Any]):
        return state.conj(), options

    def assume_full_rank(self):
        return True


__all__ = ["cholesky", "cho_solve", "spd_solve", "spd_inverse", "SPDCholesky"]

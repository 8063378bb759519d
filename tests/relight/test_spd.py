"""The fitter's small positive-definite solves (relight.fitting._spd): exact against NumPy's LAPACK, NaN
where the matrix is not positive definite (as LAPACK signals it), and no LAPACK custom call left in the
fitter's batched programs (on the CPU such a call can deadlock XLA's intra-op thread pool; the module
docstring says how)."""

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import pytest

from relight.fitting import _solvers
from relight.fitting._model import GGX_ANISO, LAMBERT, Layout
from relight.fitting._spd import SPDCholesky, cho_solve, cholesky, spd_inverse, spd_solve

# float64: a few hundred flops on matrices of condition ~1e3, rounding ~1e-13 relative.
TOL64 = 1e-10


def _spd(rng, batch, k):
    b = rng.normal(size=(*batch, k, k))
    return b @ np.swapaxes(b, -1, -2) + 0.1 * np.eye(k)


@pytest.mark.parametrize("k", [1, 2, 3, 5, 9])
def test_factor_solve_and_inverse_match_lapack(k):
    rng = np.random.default_rng(k)
    a = _spd(rng, (4, 3), k)
    b = rng.normal(size=(4, 3, k))
    L = np.asarray(cholesky(jnp.asarray(a)))
    np.testing.assert_allclose(L, np.linalg.cholesky(a), rtol=0, atol=TOL64 * np.abs(L).max())
    x_ref = np.linalg.solve(a, b[..., None])[..., 0]
    np.testing.assert_allclose(np.asarray(spd_solve(jnp.asarray(a), jnp.asarray(b))), x_ref, rtol=TOL64 * 1e2,
                               atol=TOL64 * np.abs(x_ref).max())
    np.testing.assert_allclose(np.asarray(cho_solve(jnp.asarray(L), jnp.asarray(b))), x_ref, rtol=TOL64 * 1e2,
                               atol=TOL64 * np.abs(x_ref).max())
    inv_ref = np.linalg.inv(a)
    np.testing.assert_allclose(np.asarray(spd_inverse(jnp.asarray(a))), inv_ref, rtol=0,
                               atol=TOL64 * np.abs(inv_ref).max())


def test_float32_is_as_accurate_as_its_rounding():
    rng = np.random.default_rng(7)
    a = _spd(rng, (64,), 6)
    b = rng.normal(size=(64, 6))
    x = np.asarray(spd_solve(jnp.asarray(a, jnp.float32), jnp.asarray(b, jnp.float32)))
    x_ref = np.linalg.solve(a, b[..., None])[..., 0]
    cond = np.linalg.cond(a)
    # Backward-stable: relative error below a few hundred ulps times the condition number.
    err = np.linalg.norm(x - x_ref, axis=1) / np.linalg.norm(x_ref, axis=1)
    assert np.all(err < 300 * np.finfo(np.float32).eps * cond), err.max()


def test_not_positive_definite_gives_nan_like_lapack():
    a = jnp.asarray([[1.0, 2.0], [2.0, 1.0]])  # eigenvalues 3 and -1
    assert not np.all(np.isfinite(np.asarray(spd_solve(a, jnp.ones(2)))))
    assert not np.all(np.isfinite(np.asarray(jax.scipy.linalg.cho_factor(a)[0])))


def test_lineax_solver_gives_the_least_squares_solution():
    rng = np.random.default_rng(3)
    m = rng.normal(size=(12, 5))
    y = rng.normal(size=12)
    op = lx.MatrixLinearOperator(jnp.asarray(m))
    sol = lx.linear_solve(op, jnp.asarray(y), lx.Normal(SPDCholesky()))
    ref = np.linalg.lstsq(m, y, rcond=None)[0]
    np.testing.assert_allclose(np.asarray(sol.value), ref, rtol=TOL64 * 1e2, atol=TOL64)


def test_lineax_solver_refuses_an_operator_not_known_positive():
    op = lx.MatrixLinearOperator(jnp.eye(3))
    with pytest.raises(ValueError, match="positive"):
        lx.linear_solve(op, jnp.ones(3), SPDCholesky())


@pytest.mark.parametrize("solver", ["lm", "gn", "dogleg"])
@pytest.mark.parametrize("model", [LAMBERT, GGX_ANISO])
def test_the_fitters_batched_programs_call_no_lapack(solver, model):
    lay = Layout(model, True, 0.05)
    n, obs_n = 4, 16
    f = lambda *s: jnp.zeros(s, jnp.float64)  # noqa: E731
    arrays = (f(n, obs_n, 3), f(n, obs_n, 3), f(n, obs_n, 3), f(n, obs_n, 3), f(n, obs_n, 3))
    opt, _ = _solvers.resolve_solver(solver)
    text = _solvers._solve_chunk.lower(f(n, lay.size), *arrays[:2], f(n, obs_n, 3), *arrays[2:], lay=lay,
                                       solver=opt, max_steps=3, cauchy=None).as_text()
    start = _solvers._start_chunk.lower(*arrays, lay=lay).as_text()
    assert "lapack" not in text and "lapack" not in start

"""relight.fitting.RESULTS: optimistix's result codes extended with the fitter's own (optimistix's
``_solution.py`` pattern), stored per sample as ints by one public-API map."""

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

from relight.fitting import RESULTS, result_code, result_message
from relight.fitting._result import MAX_STEPS, REJECTED, SUCCESSFUL


def test_results_extend_optimistix_with_the_rejected_solve():
    assert issubclass(RESULTS, optx.RESULTS)
    assert "keeps its start" in RESULTS[RESULTS.rejected]
    # Optimistix's items keep their meaning once promoted, and their index.
    for name in ("successful", "nonlinear_max_steps_reached", "nonfinite"):
        item = RESULTS.promote(getattr(optx.RESULTS, name))
        assert bool(item == getattr(RESULTS, name))
        assert result_message(int(result_code(item))) == RESULTS[getattr(RESULTS, name)]
    assert SUCCESSFUL == 0 and result_message(SUCCESSFUL) == ""
    assert len({SUCCESSFUL, MAX_STEPS, REJECTED}) == 3
    assert result_message(REJECTED) == RESULTS[RESULTS.rejected]


def test_result_code_is_batched_under_vmap():
    def one(ok):
        return result_code(RESULTS.where(ok, RESULTS.promote(optx.RESULTS.nonlinear_max_steps_reached),
                                         RESULTS.rejected))

    codes = jax.jit(jax.vmap(one))(jnp.array([True, False, True]))
    np.testing.assert_array_equal(np.asarray(codes), [MAX_STEPS, REJECTED, MAX_STEPS])


def test_result_code_refuses_a_foreign_item():
    with pytest.raises(TypeError, match="RESULTS"):
        result_code(optx.RESULTS.successful)

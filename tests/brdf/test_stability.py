"""Stability sweep (a moderate count here; the full 10^6 pairs per model run in
``python scripts/bench_brdf.py --sweep 1000000``): no NaN or Inf in values or in
gradients w.r.t. directions and every parameter, for every model, over random
and edge-case direction pairs and roughness from the floor to 1."""

import jax
import jax.numpy as jnp
import pytest

import brdf
from tests.brdf._util import edge_case_pairs, example_models

N_PAIRS = 1 << 12  # per dtype; every model sees every pair


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_sweep_all_models(dtype, key):
    k1, k2 = jax.random.split(key)
    wi, wo = edge_case_pairs(k1, N_PAIRS, dtype)
    models = example_models(k2, N_PAIRS, dtype)
    # One program for all models keeps the test fast; a NaN or Inf in any term
    # (value or gradient w.r.t. its own parameters) propagates into the result.
    total = brdf.Sum(*models.values())
    report = brdf.check.stability(total, wi, wo, batched=True)
    assert report == {"value": True, "grad_directions": True, "grad_params": True, "nonnegative": True}, report
    # The sweep really ran in this dtype (weakly typed defaults such as eta_a = 1 adapt).
    assert all(leaf.dtype == dtype or leaf.weak_type for leaf in jax.tree_util.tree_leaves(total))

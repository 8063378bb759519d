"""Strict test settings (after optimistix's conftest): float64 available for the
mathematics, rank promotion raises, dtype promotion is strict (no silent float32 ->
float64 or int -> float mixing), warnings are errors, and every function in brdf,
skin_bssrdf, stage and relight has its jaxtyping annotations checked at call time
(pyproject's --jaxtyping-packages, with the checker in tests/helpers.py)."""

import os
from pathlib import Path

import jax
import pytest

import tests.helpers  # noqa: F401  (the --jaxtyping-packages checker, tests.helpers.typechecker, must be loaded)

# CLI tests must not fill the user's compilation cache (~/.cache/relight/jax); tests of the cache set their own.
os.environ.setdefault("RELIGHT_CACHE_DIR", "off")

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")
jax.config.update("jax_numpy_dtype_promotion", "strict")

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture
def key():
    return jax.random.PRNGKey(5678)


@pytest.fixture
def shared_data():
    """Path to ../shared/data; skips the test with a reason when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data not found at {SHARED_DATA} (real-data tests need ../shared/data)")
    return SHARED_DATA

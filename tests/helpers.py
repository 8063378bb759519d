"""Per-dtype tolerances shared by the tests. A looser tolerance is local to its
test and carries a comment saying why."""

import jax.numpy as jnp
import numpy as np

TOL = {
    jnp.float64: dict(rtol=1e-10, atol=1e-12),
    jnp.float32: dict(rtol=1e-5, atol=1e-6),
    jnp.float16: dict(rtol=2e-3, atol=1e-3),
}


def tol(dtype):
    return TOL[jnp.dtype(dtype).type]


def assert_close(a, b, dtype=jnp.float64, **override):
    kw = dict(tol(dtype))
    kw.update(override)
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), **kw)


def assert_finite(*xs):
    for x in xs:
        for leaf in __import__("jax").tree_util.tree_leaves(x):
            assert np.all(np.isfinite(np.asarray(leaf))), "non-finite value"

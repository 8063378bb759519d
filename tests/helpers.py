"""Per-dtype tolerances shared by the tests. A looser tolerance is local to its
test and carries a comment saying why."""

import contextlib
import functools
import importlib.util
import os
import sys
from pathlib import Path

import beartype
import jax
import jax.numpy as jnp
import jaxtyping
import numpy as np

# The runtime checker behind pytest's --jaxtyping-packages (pyproject): beartype as optimistix's tests configure it
# (strategy On: every element of a container is checked, not one at random, so a failure is not left to chance),
# plus PEP 484's numeric tower, so an int passes a `float` parameter as mypy and pyright read the annotation
# (`look_at(..., fov_deg=11)` is a correct call). Named here rather than written "beartype.beartype(conf=...)" in
# pyproject: with more than one package listed, jaxtyping's plugin splits a typechecker with parentheses wrongly.
typechecker = beartype.beartype(
    conf=beartype.BeartypeConf(strategy=beartype.BeartypeStrategy.On, is_pep484_tower=True)
)

# XLA's CPU fusion emitters off for the test run (tests/conftest.py sets it, and every fresh process a test starts
# gets it through xla_flags): the suite compiles hundreds of programs that each run a few times, and with the
# emitters XLA's CPU compile takes about twice as long (the README walk's fit: 25-28 s of compile against 11-14 s,
# the same run time; test_fit.py + test_fit_sss.py: 121 s of CPU against 95 s). The arithmetic stays IEEE (no
# fast-math); only the code XLA emits for fused loops differs. Users' runs keep XLA's defaults.
# LLVM's expensive optimisation passes off as well: measured 2026-12-07, test_fit.py + test_fit_sss_texel.py
# 111.6 -> 106.4 s, the demo fixture 87.6 -> 84.8 s (the same IEEE arithmetic: no pass that reassociates).
TEST_XLA_FLAGS = "--xla_cpu_use_fusion_emitters=false --xla_llvm_disable_expensive_passes=true"


def xla_flags(*extra: str) -> str:
    """The XLA_FLAGS of a fresh process a test starts: the run's TEST_XLA_FLAGS plus ``extra`` (e.g. a forced host
    device count)."""
    return " ".join((TEST_XLA_FLAGS, *extra))


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
        for leaf in jax.tree_util.tree_leaves(x):
            assert np.all(np.isfinite(np.asarray(leaf))), "non-finite value"


# How a boundary refuses bad input: its own ValueError naming the field, or, when the argument also breaks the
# function's annotation, the test-time checker's jaxtyping.TypeCheckError (which names the parameter) first.
REFUSED = (ValueError, jaxtyping.TypeCheckError)


SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def load_script(name: str):
    """Import ``scripts/<name>.py`` as a module, as ``python scripts/<name>.py`` would see it: with the scripts'
    folder first on ``sys.path`` while it loads (for ``scripts/_common.py``), and registered under ``name`` in
    ``sys.modules`` (dataclasses and equinox Modules look their module up by name)."""
    spec = importlib.util.spec_from_file_location(name, SCRIPTS / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    sys.path.insert(0, str(SCRIPTS))
    try:
        spec.loader.exec_module(mod)
    finally:
        sys.path.remove(str(SCRIPTS))
    return mod


def run_root(tmp_path_factory) -> Path:
    """The test run's temporary folder, shared by the xdist workers (never the user's)."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


@contextlib.contextmanager
def locked(path: Path):
    """An exclusive lock on ``path`` across processes (fcntl; where there is none, no lock: each process
    builds its own copy)."""
    try:
        import fcntl
    except ImportError:
        yield
        return
    with open(path, "w") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        yield  # closing the file releases the lock


def fjit(fun=None, **kw):
    """jax.jit with brdf.check.FAST_COMPILE: the test programs that run once or a few times on small arrays,
    where compile time is what the suite pays for (eager, every op compiles on its own). The arithmetic stays
    IEEE (no fast-math). Usable as ``@fjit`` or ``@fjit(static_argnames=...)``."""
    import brdf  # here, not at the top: this module (its typechecker) loads before the instrumented packages

    if fun is None:
        return functools.partial(fjit, **kw)
    return jax.jit(fun, compiler_options=brdf.check.FAST_COMPILE, **kw)


def grad_and_central_differences(f, x, h: float):
    """(jax.grad(f)(x), the central differences (f(x + h e_i) - f(x - h e_i)) / 2h along each axis) of a scalar
    ``f`` of a vector ``x``, as one program (fjit): the gradient and the 2n shifted values compiled once."""
    steps = h * jnp.eye(x.shape[0], dtype=x.dtype)
    g, up, down = fjit(lambda x, s: (jax.grad(f)(x), jax.lax.map(f, x[None] + s), jax.lax.map(f, x[None] - s)))(
        x, steps)
    return g, (up - down) / (2 * h)

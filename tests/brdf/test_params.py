"""Fittable-parameter descriptions, the unconstrained transforms and parameter paths."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdf
from tests.brdf._util import ev, fjit
from tests.helpers import assert_close, assert_finite


@pytest.mark.parametrize(
    "spec",
    [
        brdf.ParamSpec(0.0, 1.0, "sigmoid"),
        brdf.ParamSpec(1e-4, 1.0, "sigmoid"),
        brdf.ParamSpec(0.01, float("inf"), "softplus"),
        brdf.ParamSpec(0.0, float("inf"), "exp"),
        brdf.ParamSpec(-float("inf"), float("inf"), "identity"),
    ],
)
def test_round_trip(spec):
    # Interior values come back to float64 rounding after u = to(x), x = from(u).
    lo = spec.lower if np.isfinite(spec.lower) else -3.0
    hi = spec.upper if np.isfinite(spec.upper) else lo + 50.0
    x = jnp.linspace(lo, hi, 11)[1:-1]
    u = brdf.to_unconstrained(spec, x)
    assert_finite(u)
    assert_close(brdf.from_unconstrained(spec, u), x, rtol=1e-9, atol=1e-12)
    # from_unconstrained maps any real into the bounds.
    y = brdf.from_unconstrained(spec, jnp.asarray([-30.0, 0.0, 30.0]))
    assert np.all(np.asarray(y) >= spec.lower) and np.all(np.asarray(y) <= spec.upper)


def test_to_unconstrained_at_bounds_is_finite():
    spec = brdf.ParamSpec(0.0, 1.0, "sigmoid")
    u = brdf.to_unconstrained(spec, jnp.asarray([0.0, 1.0, -1.0, 2.0], jnp.float32))
    assert_finite(u)
    assert np.all(np.diff(np.asarray(u)[:2]) > 0)  # order kept: lower bound maps below upper
    sp = brdf.ParamSpec(0.0, float("inf"), "softplus")
    assert_finite(brdf.to_unconstrained(sp, jnp.asarray([0.0, 1e-30, 1e4])))


@pytest.mark.parametrize(
    "args", [(1.0, 0.0, "sigmoid"), (0.0, 1.0, "tanh"), (0.0, float("inf"), "sigmoid"), (-float("inf"), 0.0, "exp")]
)
def test_bad_specs_raise(args):
    with pytest.raises(ValueError):
        brdf.ParamSpec(*args)


def test_lambert_ggx_fittable_paths():
    rho_d = jnp.full((5, 3), 0.4)
    f0 = jnp.full((5, 1), 0.04)
    alpha = jnp.full((5, 1), 0.25)
    m = brdf.lambert_ggx(rho_d, f0, alpha)
    specs = m.fittable()
    assert set(specs) == {"terms.0.albedo", "terms.1.fresnel.f0", "terms.1.distribution.alpha_x"}
    assert specs["terms.1.distribution.alpha_x"].lower == brdf.ALPHA_MIN
    got = brdf.get_params(m)
    assert_close(got["terms.0.albedo"], rho_d)
    assert_close(got["terms.1.fresnel.f0"], f0)
    assert_close(got["terms.1.distribution.alpha_x"], alpha)


def test_set_params_round_trip_under_jit_and_grad(key):
    m = brdf.lambert_ggx(jnp.full((1, 3), 0.4), jnp.full((1, 1), 0.04), jnp.full((1, 1), 0.25))
    specs = m.fittable()
    u0 = {n: brdf.to_unconstrained(specs[n], v) for n, v in brdf.get_params(m).items()}
    wi = jnp.asarray([[0.3, 0.1, 0.948683]])
    wo = jnp.asarray([[-0.2, 0.0, 0.979796]])

    def loss(u):
        x = {n: brdf.from_unconstrained(specs[n], v) for n, v in u.items()}
        return jnp.sum(brdf.set_params(m, x)(wi, wo) ** 2)

    # The unconstrained round trip reproduces the model's value exactly (to rounding).
    assert_close(fjit(loss)(u0), jnp.sum(ev(m, wi, wo) ** 2), rtol=1e-9)
    g = fjit(jax.grad(loss))(u0)
    assert_finite(g)
    # A rougher lobe at this near-mirror pair lowers the peak: the gradient is not zero.
    assert all(float(jnp.max(jnp.abs(v))) > 0 for v in jax.tree_util.tree_leaves(g))


def test_unknown_param_name_raises():
    m = brdf.Lambert(0.5)
    with pytest.raises(ValueError, match="no parameter"):
        brdf.set_params(m, {"rho": 0.2})

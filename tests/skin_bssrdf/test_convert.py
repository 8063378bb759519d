"""(sigma_a, sigma_s', eta) <-> (albedo, mean free path): round trips, gradients, edges."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import skin_bssrdf as sb
from tests.helpers import assert_close, assert_finite, fjit, grad_and_central_differences

MODELS = ["dipole", "better_dipole"]
RD = jnp.array([0.0, 0.01, 0.2, 0.5, 0.8, 0.95, 0.999])


@pytest.mark.parametrize("model", MODELS)
def test_inversion_round_trip(model):
    a = sb.reduced_albedo_from_total(RD, 1.35, model)
    assert_close(sb.total_from_reduced_albedo(a, 1.35, model), RD, atol=1e-12)
    assert np.all(np.diff(np.asarray(a)) > 0)


@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("kind", ["diffuse", "transport"])
def test_coefficients_round_trip(model, kind):
    rd = RD[1:]
    mfp = jnp.linspace(0.5, 4.0, rd.shape[0])

    @fjit  # the round trip and the profile in one program
    def trip(rd, mfp):
        sa, ss = sb.coefficients_from_albedo(rd, mfp, 1.3, model, kind)
        rd2, mfp2 = sb.albedo_from_coefficients(sa, ss, 1.3, model, kind)
        # and the profile built from them has that total and that width
        P = (sb.Dipole if model == "dipole" else sb.BetterDipole)(sa, ss, 1.3)
        return rd2, mfp2, P.total(), 1 / P.sigma_tr

    rd2, mfp2, total, width = trip(rd, mfp)
    assert_close(rd2, rd, atol=1e-12)
    assert_close(mfp2, mfp, rtol=1e-10)
    assert_close(total, rd, atol=1e-12)
    if kind == "diffuse":
        assert_close(width, mfp, rtol=1e-10)


@pytest.mark.parametrize("model", MODELS)
def test_gradients_finite_at_albedo_0_and_1(model):
    def f(rd):
        sa, ss = sb.coefficients_from_albedo(rd, 2.0, 1.3, model)
        st, tt = sb.coefficients_from_albedo(rd, 2.0, 1.3, model, "transport")
        return jnp.sum(sa + 2 * ss + st + 3 * tt) + jnp.sum(sb.reduced_albedo_from_total(rd, 1.3, model))

    vals, g = fjit(jax.value_and_grad(f))(jnp.array([0.0, 1.0]))
    assert_finite(g)
    assert np.isfinite(float(vals))


@pytest.mark.parametrize("model", MODELS)
def test_gradient_matches_finite_differences(model):
    def f(x):
        sa, ss = sb.coefficients_from_albedo(x[0], x[1], x[2], model)
        return jnp.sum(sa * 3 + ss)

    x = jnp.array([0.45, 1.7, 1.35])
    h = 1e-6
    g, fd = grad_and_central_differences(f, x, h)
    assert_close(g, fd, rtol=1e-6, atol=1e-8)


def test_float32_stable():
    rd = jnp.array([0.0, 0.3, 0.9, 0.99, 1.0], jnp.float32)
    sa, ss = sb.coefficients_from_albedo(rd, jnp.float32(1.5), jnp.float32(1.3))
    assert sa.dtype == jnp.float32
    grad = jax.grad(lambda r: jnp.sum(sum(sb.coefficients_from_albedo(r, jnp.float32(1.5), jnp.float32(1.3)))))(rd)
    assert_finite(sa, ss, grad)
    rd2, _ = sb.albedo_from_coefficients(sa, ss, jnp.float32(1.3))
    # float32 conditioning near albedo 1 (Rd ~ 1 - c sqrt(1 - alpha')) costs ~1e-4 there
    assert_close(rd2, rd, dtype=jnp.float32, atol=1e-4, rtol=0)


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: sb.coefficients_from_albedo(1.2, 1.0), "albedo"),
        (lambda: sb.coefficients_from_albedo(0.5, 0.0), "mfp"),
        (lambda: sb.coefficients_from_albedo(0.5, 1.0, 1.3, "bogus"), "model"),
        (lambda: sb.coefficients_from_albedo(0.5, 1.0, 1.3, "dipole", "bogus"), "mfp_kind"),
        (lambda: sb.albedo_from_coefficients(-0.1, 1.0), "sigma_a"),
        (lambda: sb.reduced_albedo_from_total(0.5, 0.9), "eta"),
    ],
)
def test_invalid_input_raises(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_traced_invalid_input_does_not_raise():
    # checks run on concrete values only: under jit an out-of-range albedo is clipped, not raised on
    out = jax.jit(lambda r: sb.reduced_albedo_from_total(r))(jnp.array(1.5))
    assert_finite(out)

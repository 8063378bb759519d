"""Classical dipole (Jensen et al. 2001): closed forms, quadrature, gradients, edges."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import skin_bssrdf as sb
from tests.helpers import assert_close, assert_finite
from tests.skin_bssrdf.quadrature import integrate_disc

# Skin1 of Jensen et al. 2001's measured table (1/mm), eta = 1.3.
SKIN1 = dict(sigma_a=jnp.array([0.032, 0.17, 0.48]), sigma_s_prime=jnp.array([0.74, 0.88, 1.01]), eta=1.3)


def test_total_matches_quadrature():
    # total() is eq. 5; the quadrature integrates eq. 4 numerically. 1e-4 absolute is the required agreement;
    # the closed forms are exact, so it also holds at 1e-8 relative in float64.
    albedo = jnp.array([0.0, 0.05, 0.3, 0.7, 0.95, 0.999])
    st = 1.7
    d = sb.Dipole(sigma_a=(1 - albedo) * st, sigma_s_prime=albedo * st, eta=1.4)
    q = integrate_disc(d, r_max=1e3)
    assert_close(q, d.total(), rtol=1e-8, atol=1e-12)
    assert_close(d.cumulative(1e3), q, rtol=1e-8, atol=1e-12)
    # sigma_a = 0: R_d ~ 1/r^3 far out, the tail beyond r_max = 1e5 carries ~1e-5 of the energy
    d1 = sb.Dipole(0.0, st, 1.4)
    assert_close(integrate_disc(d1, r_max=1e5), d1.total(), atol=1e-4, rtol=0)


def test_skin1_totals_known_values():
    # Jensen et al. 2001's table lists Rd = 0.44, 0.22, 0.13 for skin1 (two decimals); its own
    # eq. 5 gives 0.436, 0.227, 0.131 (the table's column is reproduced to 0.008, see test_presets).
    d = sb.Dipole(**SKIN1)
    assert_close(d.total(), [0.4359564, 0.2273312, 0.1309988], rtol=1e-6, atol=0)
    assert_close(d.total(), [0.44, 0.22, 0.13], atol=0.008, rtol=0)


def test_energy_conserved_without_absorption():
    # alpha' = 1: every photon leaves, for any index mismatch (eq. 5 with alpha' = 1 gives 1).
    d = sb.Dipole(0.0, jnp.array([0.5, 1.0, 2.0]), jnp.array([1.0, 1.3, 2.0]))
    assert_close(d.total(), jnp.ones(3))


def test_profile_falls_and_is_positive():
    d = sb.Dipole(**SKIN1)
    r = jnp.linspace(0.0, 30.0, 3001)
    R = d.radial(r)
    assert R.shape == (3001, 3)
    assert np.all(np.asarray(R) > 0)
    assert np.all(np.diff(np.asarray(R), axis=0) < 0)


def test_shapes_and_broadcast():
    d = sb.Dipole(0.1, 1.0, 1.3)
    assert d.radial(1.0).shape == (1,)
    assert d.radial(jnp.ones((4, 5))).shape == (4, 5, 1)
    # a texture of parameters [P, C] evaluated at r [P]
    dp = sb.Dipole(jnp.full((7, 3), 0.1), jnp.full((7, 3), 1.0), 1.3)
    out = dp.radial(jnp.linspace(0, 1, 7))
    assert out.shape == (7, 3)
    assert_close(out[3], sb.Dipole(jnp.full(3, 0.1), jnp.full(3, 1.0), 1.3).radial(0.5))


def test_gradient_matches_finite_differences():
    # all three parameters at once (the profile-generic test varies the albedo only)
    @jax.jit
    def f(x):
        d = sb.Dipole(x[0], x[1], x[2])
        return d.radial(jnp.array([0.0, 0.3, 2.0])).sum() + d.total().sum()

    x = jnp.array([0.05, 1.2, 1.35])
    h = 1e-6
    fd = jnp.array([(f(x + h * e) - f(x - h * e)) / (2 * h) for e in jnp.eye(3)])
    assert_close(jax.grad(f)(x), fd, rtol=1e-6, atol=1e-9)  # central differences, h = 1e-6: O(h^2) + rounding
    # the profile is smooth and even in r: zero slope at r = 0
    gr = jax.jit(jax.grad(lambda r: sb.Dipole(**SKIN1).radial(r).sum()))(0.0)
    assert_close(gr, 0.0)


def test_float32_finite_and_close():
    d64 = sb.Dipole(**SKIN1)
    d32 = sb.Dipole(SKIN1["sigma_a"].astype(jnp.float32), SKIN1["sigma_s_prime"].astype(jnp.float32), jnp.float32(1.3))
    r = jnp.linspace(0, 10, 50, dtype=jnp.float32)
    assert d32.radial(r).dtype == jnp.float32
    assert_finite(d32.radial(r), d32.total())
    assert_close(d32.radial(r), d64.radial(r.astype(jnp.float64)), dtype=jnp.float32, rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(sigma_a=-0.1, sigma_s_prime=1.0), "sigma_a"),
        (dict(sigma_a=0.1, sigma_s_prime=-1.0), "sigma_s_prime"),
        (dict(sigma_a=0.0, sigma_s_prime=0.0), "sigma_a \\+ sigma_s_prime"),
        (dict(sigma_a=0.1, sigma_s_prime=1.0, eta=0.8), "eta"),
        (dict(sigma_a=float("nan"), sigma_s_prime=1.0), "finite"),
    ],
)
def test_invalid_input_raises(kwargs, match):
    with pytest.raises(ValueError, match=match):
        sb.Dipole(**kwargs)


def test_negative_radius_raises_but_traced_does_not():
    d = sb.Dipole(**SKIN1)
    with pytest.raises(ValueError, match="radius"):
        d.radial(-1.0)
    # under jit the value is not visible: no check, no error
    assert_finite(jax.jit(lambda r: d.radial(r))(jnp.array(1.0)))

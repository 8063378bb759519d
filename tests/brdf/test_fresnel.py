"""Fresnel terms: closed forms at normal incidence, agreement between the exact
forms, limits, and finite gradients at the edges."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdf
from tests.brdf._util import fjit
from tests.helpers import assert_close, assert_finite

COS = jnp.linspace(0.0, 1.0, 101)[:, None]  # [101, 1], includes grazing (0) and normal (1)


def test_conductor_normal_incidence_closed_form():
    eta = jnp.asarray([[0.2, 1.5, 3.0]])
    k = jnp.asarray([[3.9, 0.0, 1.2]])
    f = brdf.fresnel_conductor(jnp.ones((1, 1)), eta, k)
    assert_close(f, ((eta - 1) ** 2 + k**2) / ((eta + 1) ** 2 + k**2))
    m = brdf.ConductorFresnel(eta, k)
    assert_close(m(jnp.ones((1, 1))), f)


def test_dielectric_matches_complex_with_zero_k():
    # The two exact forms are written independently; with k = 0 they must agree,
    # total internal reflection (eta < 1) included.
    for eta in (1.5, 1.0 / 1.33, 2.4):
        assert_close(brdf.fresnel_dielectric(COS, eta), brdf.fresnel_complex(COS, eta, 0.0), atol=1e-12)
    assert_close(brdf.fresnel_dielectric(jnp.ones((1, 1)), 1.5), [[0.04]])
    # Beyond the critical angle (sin > 1/1.33) reflection is total.
    assert_close(brdf.fresnel_dielectric(jnp.asarray([[0.1]]), 1 / 1.33), [[1.0]])


def test_two_media_reduce_to_relative_index():
    # A dielectric ambient medium eta_a: the relative index (eta_m + i kappa_m) / eta_a.
    f2 = brdf.fresnel_complex(COS, 0.5, 2.5, eta_a=1.33, kappa_a=0.0)
    f1 = brdf.fresnel_conductor(COS, 0.5 / 1.33, 2.5 / 1.33)
    assert_close(f2, f1)


def test_limits_and_range():
    for f in (
        brdf.fresnel_conductor(COS, 0.2, 3.9),
        brdf.fresnel_dielectric(COS, 1.5),
        brdf.schlick(COS, 0.04),
    ):
        v = np.asarray(f)
        assert v.min() >= 0 and v.max() <= 1 + 1e-15
        assert_close(v[0], [1.0])  # every Fresnel term is 1 at grazing incidence
    assert_close(brdf.schlick(jnp.ones((1, 1)), 0.3), [[0.3]])


def test_schlick_tracks_exact_dielectric():
    # Schlick 1994 approximates the dielectric closely; its worst absolute error for
    # eta = 1.5 is 0.036, near cos = 0.09 (measured here with 1001 points).
    f0 = ((1.5 - 1) / (1.5 + 1)) ** 2
    err = np.abs(np.asarray(brdf.schlick(COS, f0) - brdf.fresnel_dielectric(COS, 1.5)))
    assert err.max() < 0.04
    assert err[90:].max() < 1e-3  # near normal incidence (cos >= 0.9) they agree to 1e-3


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_finite_gradients(dtype):
    c = COS.astype(dtype)

    def total(p, c):
        return (
            jnp.sum(brdf.fresnel_conductor(c, p["eta"], p["k"]))
            + jnp.sum(brdf.fresnel_dielectric(c, p["eta"]))
            + jnp.sum(brdf.fresnel_dielectric(c, 1 / p["eta"]))
            + jnp.sum(brdf.schlick(c, p["f0"]))
        )

    # Matched indices (eta = 1, k = 0 or tiny), a dielectric, a metal; one compile.
    eta = jnp.asarray([[1.0, 1.5, 0.2, 1.0]], dtype)
    k = jnp.asarray([[0.0, 0.0, 3.9, 1e-8]], dtype)
    p = {"eta": eta, "k": k, "f0": jnp.asarray(0.04, dtype)}
    g = fjit(jax.grad(total, argnums=(0, 1)))(p, c)
    assert_finite(g)


def test_invalid_parameters_raise():
    with pytest.raises(ValueError, match="eta"):
        brdf.ConductorFresnel(0.0, 1.0)
    with pytest.raises(ValueError, match="'k'"):
        brdf.ConductorFresnel(1.0, -1.0)
    with pytest.raises(ValueError, match="eta"):
        brdf.DielectricFresnel(-1.5)

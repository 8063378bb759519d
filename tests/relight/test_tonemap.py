"""Tone mapping and the sRGB transfer: closed-form values, inverse pairs, the
kornia (independent PyTorch) implementation, and no NaN on any input."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from relight.image import srgb_decode, srgb_encode, to_uint8, to_uint16, tonemap
from tests.helpers import assert_close, assert_finite


def test_srgb_known_values():
    x = jnp.array([0.0, 0.0031308, 0.18, 0.5, 1.0], jnp.float64)
    # IEC 61966-2-1: 12.92 x below the knee, 1.055 x^(1/2.4) - 0.055 above.
    expect = np.array([0.0, 12.92 * 0.0031308, 1.055 * 0.18 ** (1 / 2.4) - 0.055, 1.055 * 0.5 ** (1 / 2.4) - 0.055,
                       1.0])
    assert_close(srgb_encode(x), expect)
    # The two branches meet at the knee (continuity to the standard's rounding, ~1e-7).
    assert abs(1.055 * 0.0031308 ** (1 / 2.4) - 0.055 - 12.92 * 0.0031308) < 1e-7


def test_srgb_inverse_pair():
    x = jnp.linspace(0.0, 1.0, 2001, dtype=jnp.float64)
    assert_close(srgb_decode(srgb_encode(x)), x, atol=1e-12)
    assert_close(srgb_encode(srgb_decode(x)), x, atol=1e-12)


def test_srgb_matches_kornia():
    torch = pytest.importorskip("torch")
    kornia = pytest.importorskip("kornia")
    rng = np.random.default_rng(3)
    img = rng.random((3, 16, 16))  # kornia works on [C, H, W]
    t = torch.from_numpy(img)
    enc_k = kornia.color.linear_rgb_to_rgb(t).numpy()
    dec_k = kornia.color.rgb_to_linear_rgb(t).numpy()
    # Same formulas evaluated in float64 by two libraries: agree to rounding.
    assert_close(srgb_encode(jnp.asarray(img)), enc_k, atol=1e-12)
    assert_close(srgb_decode(jnp.asarray(img)), dec_k, atol=1e-12)


@pytest.mark.parametrize("curve", ["reinhard", "filmic", "none"])
def test_tonemap_range_monotone_and_finite(curve):
    x = jnp.concatenate([jnp.array([-1.0, 0.0, jnp.inf, jnp.nan]), jnp.logspace(-6, 6, 500)])
    y = tonemap(x, curve=curve)
    assert_finite(y)
    assert float(y.min()) >= 0.0 and float(y.max()) <= 1.0
    assert float(y[0]) == 0.0 and float(y[1]) == 0.0 and float(y[3]) == 0.0  # negative, 0, NaN -> black
    assert np.all(np.diff(np.asarray(y[4:])) >= 0)  # monotone in radiance


def test_tonemap_closed_forms_and_exposure():
    x = jnp.array([0.25, 1.0, 3.0], jnp.float64)
    assert_close(tonemap(x, curve="reinhard"), srgb_encode(x / (1 + x)))
    assert_close(tonemap(x, curve="none"), srgb_encode(jnp.minimum(x, 1.0)))
    # Exposure is in stops: +1 stop on x equals x doubled.
    assert_close(tonemap(x, exposure=1.0), tonemap(2 * x))
    aces = lambda v: np.clip(v * (2.51 * v + 0.03) / (v * (2.43 * v + 0.59) + 0.14), 0, 1)  # noqa: E731
    assert_close(tonemap(x, curve="filmic"), srgb_encode(aces(np.asarray(x))))
    with pytest.raises(ValueError, match="unknown tone curve"):
        tonemap(x, curve="hable")


def test_tonemap_jit_grad_finite_at_zero():
    f = jax.jit(lambda v: jnp.sum(tonemap(v, curve="filmic")))
    g = jax.grad(f)(jnp.array([0.0, 1e-9, 1.0, 1e6]))
    assert_finite(g)
    assert float(g[2]) > 0


def test_quantisers():
    x = np.array([-0.5, 0.0, 0.5 / 255, 0.5, 1.0, 2.0, np.nan])
    np.testing.assert_array_equal(to_uint8(x), [0, 0, 0, 128, 255, 255, 0])  # 0.5/255 rounds half to even
    assert to_uint16(np.array([1.0]))[0] == 65535 and to_uint16(np.array([0.5]))[0] == 32768

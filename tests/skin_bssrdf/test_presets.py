"""Jensen et al. 2001's measured table: the Rd column from the coefficients."""

import jax.numpy as jnp
import numpy as np
import pytest

import skin_bssrdf as sb
from tests.helpers import assert_close


@pytest.mark.parametrize("name", sorted(sb.JENSEN2001))
def test_table_rd_column_reproduced(name):
    m = sb.JENSEN2001[name]
    rd = np.asarray(sb.preset(name).total())
    # the column has two decimals; eq. 5 reproduces it within 0.008 everywhere except
    # chicken1's blue channel (0.126 against 0.10: the paper's own discrepancy, see _presets.py)
    tol = np.full(3, 0.008)
    if name == "chicken1":
        tol[2] = 0.03
    assert np.all(np.abs(rd - np.asarray(m.rd)) <= tol), (rd, m.rd)


def test_marble_needs_eta_1_5():
    m = sb.JENSEN2001["marble"]
    rd13 = np.asarray(sb.Dipole(jnp.asarray(m.sigma_a), jnp.asarray(m.sigma_s_prime), 1.3).total())
    assert np.all(np.abs(rd13 - np.asarray(m.rd)) > 0.03)  # why the preset carries eta = 1.5


def test_preset_models():
    b = sb.preset("skin1", model="better_dipole")
    assert isinstance(b, sb.BetterDipole)
    assert_close(sb.preset("Skin 1").sigma_a, [0.032, 0.17, 0.48])

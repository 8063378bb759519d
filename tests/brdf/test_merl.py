"""MERL format: Rusinkiewicz coordinates, the format's indexing against a
line-by-line port of MERL's BRDFRead.cpp, file round trips, tabulated evaluation."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdf
from relight.io import write_merl
from tests.brdf._util import edge_case_pairs, ev, ev_pairs, fjit
from tests.helpers import assert_close

RES_TH, RES_TD, RES_PD = 90, 90, 360  # BRDFRead.cpp constants (phi_d stored over half: 180)


# ---- a plain-Python port of MERL's reference code, kept independent of brdf ----
def _rotate(v, axis, angle):
    c, s = math.cos(angle), math.sin(angle)
    dot = sum(a * b for a, b in zip(v, axis, strict=True))
    cross = (axis[1] * v[2] - axis[2] * v[1], axis[2] * v[0] - axis[0] * v[2], axis[0] * v[1] - axis[1] * v[0])
    return tuple(v[i] * c + axis[i] * dot * (1 - c) + cross[i] * s for i in range(3))


def _ref_index(wi, wo):
    h = [a + b for a, b in zip(wi, wo, strict=True)]
    n = math.sqrt(sum(x * x for x in h))
    h = [x / n for x in h]
    theta_h = math.acos(max(-1.0, min(1.0, h[2])))
    phi_h = math.atan2(h[1], h[0])
    tmp = _rotate(wi, (0.0, 0.0, 1.0), -phi_h)
    diff = _rotate(tmp, (0.0, 1.0, 0.0), -theta_h)
    theta_d = math.acos(max(-1.0, min(1.0, diff[2])))
    phi_d = math.atan2(diff[1], diff[0])
    # theta_half_index
    if theta_h <= 0.0:
        ih = 0
    else:
        ih = int(math.sqrt(theta_h / (math.pi / 2.0) * RES_TH * RES_TH))
        ih = min(max(ih, 0), RES_TH - 1)
    idd = min(max(int(theta_d / (math.pi * 0.5) * RES_TD), 0), RES_TD - 1)
    if phi_d < 0.0:
        phi_d += math.pi
    ip = min(max(int(phi_d / math.pi * RES_PD / 2), 0), RES_PD // 2 - 1)
    return ih, idd, ip


def test_indexing_matches_reference_code(key):
    wi, wo = brdf.check.random_pairs(key, 500)
    # Add exact configurations: normal incidence, wi = wo, mirror pairs.
    wi = jnp.concatenate([wi, jnp.asarray([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.6, 0.0, 0.8]])])
    wo = jnp.concatenate([wo, jnp.asarray([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [-0.6, 0.0, 0.8]])])
    ih, idd, ip = (np.asarray(x) for x in fjit(brdf.merl_index)(wi, wo))
    ref = np.asarray(
        [
            _ref_index(tuple(map(float, a)), tuple(map(float, b)))
            for a, b in zip(np.asarray(wi), np.asarray(wo), strict=True)
        ]
    )
    # Directions a rounding error away from a bin edge may fall either side: allow
    # at most 1% of lookups to differ, and by one bin only.
    diff = np.abs(np.stack([ih, idd, ip], -1) - ref)
    assert np.mean(np.any(diff > 0, axis=-1)) <= 0.01
    assert diff.max() <= 1


def test_half_diff_round_trip(key):
    wi, wo = brdf.check.random_pairs(key, 1000)
    wi2, wo2 = fjit(lambda a, b: brdf.half_diff_to_directions(*brdf.half_diff_coords(a, b)))(wi, wo)
    assert_close(wi2, wi, atol=1e-12)
    assert_close(wo2, wo, atol=1e-12)
    # theta_h of a mirror pair is 0 and theta_d is the angle of incidence.
    th, _, td, _ = fjit(brdf.half_diff_coords)(jnp.asarray([0.6, 0.0, 0.8]), jnp.asarray([-0.6, 0.0, 0.8]))
    assert_close(th, 0.0, atol=1e-15)
    assert_close(td, math.acos(0.8))


@pytest.fixture(scope="module")
def table():
    # Lambert plus a GGX lobe: an isotropic, reciprocal analytic model with colour.
    m = brdf.Sum(brdf.Lambert(jnp.asarray([0.2, 0.3, 0.4])), brdf.Microfacet(brdf.GGX(0.3), brdf.SchlickFresnel(0.04)))
    return m, brdf.tabulate_merl(m)


def test_file_round_trip(tmp_path, table):
    model, tab = table
    path = tmp_path / "model.binary"
    write_merl(path, tab)
    raw = path.read_bytes()
    assert len(raw) == 12 + 8 * 3 * 90 * 90 * 180
    assert np.frombuffer(raw[:12], "<i4").tolist() == [90, 90, 180]
    # channel scales: the stored red value is f_r * 1500
    assert_close(np.frombuffer(raw[12:20], "<f8")[0], float(tab[0, 0, 0, 0]) * 1500.0)
    back = brdf.read_merl(path)
    assert_close(back.table, tab, rtol=1e-15, atol=0)
    assert list(tmp_path.iterdir()) == [path]  # the atomic write left no temporary file


def test_tabulated_evaluation(table):
    model, tab = table
    merl = brdf.MERL(tab)
    # At bin centres (any phi_h: the model is isotropic) nearest lookup is exact.
    th, td, pd = brdf.merl_bin_centers()
    i, j, k = np.array([0, 7, 40, 80]), np.array([0, 20, 60, 10]), np.array([0, 90, 179, 33])
    wi, wo = fjit(brdf.half_diff_to_directions)(th[i], jnp.asarray([0.0, 1.0, 2.0, -2.5]), td[j], pd[k])
    assert_close(ev(merl, wi, wo), tab[:, i, j, k].T, rtol=1e-12)
    # Off the grid, away from the horizon, interpolation tracks the smooth model.
    wi, wo = brdf.check.random_pairs(jax.random.PRNGKey(3), 4000)
    keep = (wi[:, 2] > 0.3) & (wo[:, 2] > 0.3)
    wi, wo = wi[keep], wo[keep]
    ref = ev_pairs(model, wi, wo)

    @fjit
    def lookups(t, wi, wo):
        # and missing (negative) entries, which read as 0
        return brdf.MERL(t, "nearest")(wi, wo), brdf.MERL(t, "linear")(wi, wo), brdf.MERL(-t)(wi, wo)

    near, lin, missing = lookups(tab, wi, wo)
    err_near = np.median(np.abs(np.asarray(near / ref - 1)))
    err_lin = np.median(np.abs(np.asarray(lin / ref - 1)))
    assert err_lin < 2e-4 and err_near < 5e-3, (err_lin, err_near)  # bins ~1 degree wide
    assert err_lin < err_near
    # Below the horizon the table gives 0; missing (negative) entries read as 0.
    below = ev(merl, jnp.asarray([[0.0, 0.6, -0.8]]), jnp.asarray([[0.0, 0.0, 1.0]]))
    assert_close(below, [[0.0, 0.0, 0.0]])
    assert float(jnp.max(jnp.abs(missing))) == 0.0


def test_linear_lookup_gradients_are_finite(table):
    _, tab = table
    wi, wo = edge_case_pairs(jax.random.PRNGKey(4), 512)
    g = fjit(jax.grad(lambda a, b: jnp.sum(brdf.MERL(tab, "linear")(a, b)), argnums=(0, 1)))(wi, wo)
    assert all(bool(jnp.all(jnp.isfinite(x))) for x in g)


def test_bad_files_raise(tmp_path):
    short = tmp_path / "short.binary"
    short.write_bytes(np.asarray([90, 90, 180], "<i4").tobytes() + b"\0" * 80)
    with pytest.raises(ValueError, match="short.binary.*bytes"):
        brdf.read_merl(short)
    dims = tmp_path / "dims.binary"
    dims.write_bytes(np.asarray([90, 90, 90], "<i4").tobytes())
    with pytest.raises(ValueError, match="dims.binary.*dims"):
        brdf.read_merl(dims)
    with pytest.raises(ValueError, match="shape"):
        write_merl(tmp_path / "x.binary", np.zeros((3, 90, 90, 90)))

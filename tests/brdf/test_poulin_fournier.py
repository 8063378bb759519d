"""Poulin-Fournier 1990 (parallel cylinders): the shadowing geometry against an
independent ray-cast of the cross-section, reciprocity, anisotropy, its limits,
energy, quadrature error, and finite values and gradients at the edges."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdf
import brdf._poulin_fournier as pf
from tests.brdf._util import edge_case_pairs, edge_directions, ev_pairs, fjit, from_cos
from tests.helpers import assert_close, assert_finite

GEOMETRIES = [(0.0, 1.0), (0.5, 1.0), (0.0, 0.5), (0.5, 0.5), (2.0, 0.2)]  # (spacing d, height h)


def _ray_cast_reference(wi, wo, rho_d, rho_s, n, d, h, m=20000):
    """f_r by brute force, written independently of the model: the cross-section
    of one period sampled at m midpoints per cap (and as densely on the base);
    a point counts when it faces both directions and the 2-D rays towards wi
    and wo miss every cylinder disc (radius 1, centres (k P, h - 1)) but its own."""
    t_max = np.arccos(1 - h)
    c, w = h - 1, np.sin(t_max)
    period = 2 * w + d
    t = -t_max + (np.arange(m) + 0.5) * (2 * t_max / m)
    mb = int(m * d / (2 * t_max))
    yb = w + (np.arange(mb) + 0.5) * (d / max(mb, 1))
    parts = [
        (np.stack([np.sin(t), c + np.cos(t)], -1), np.stack([0 * t, np.sin(t), np.cos(t)], -1), 2 * t_max / m, True),
        (np.stack([yb, 0 * yb], -1), np.tile([0.0, 0.0, 1.0], (mb, 1)), d / max(mb, 1), False),
    ]

    def lit(x, nrm, v, own):
        ray = v[1:] / np.linalg.norm(v[1:])
        ok = nrm @ v > 0
        for k in range(-4, 5):
            if own and k == 0:
                continue
            q = x - np.array([k * period, c])
            b = q @ ray
            disc = b * b - ((q * q).sum(-1) - 1)
            ok &= ~((disc > 0) & (-b + np.sqrt(np.maximum(disc, 0)) > 1e-12))
        return ok

    total = 0.0
    for x, nrm, dl, own in parts:
        if len(x) == 0:
            continue
        r = 2 * (nrm @ wi)[:, None] * nrm - wi
        f_mu = rho_d / np.pi + rho_s * (n + 2) / (2 * np.pi) * np.maximum(r @ wo, 0) ** n
        vis = lit(x, nrm, wi, own) & lit(x, nrm, wo, own)
        total += np.sum(f_mu * (nrm @ wi) * (nrm @ wo) * vis) * dl
    return total / (period * wi[2] * wo[2])


def test_shadowing_matches_ray_cast():
    rng = np.random.default_rng(3)
    cos_i = np.concatenate([[0.03, 0.1, 0.9, 0.5], rng.uniform(0.05, 1, 4)])
    cos_o = np.concatenate([[0.5, 0.04, 0.2, 0.5], rng.uniform(0.05, 1, 4)])
    wi = np.asarray(from_cos(cos_i, rng.uniform(0, 2 * np.pi, 8)))
    wo = np.asarray(from_cos(cos_o, rng.uniform(0, 2 * np.pi, 8)))
    for d, h in GEOMETRIES:
        m = brdf.PoulinFournier(0.3, 0.6, 20.0, d, h)
        ours = np.asarray(ev_pairs(m, jnp.asarray(wi), jnp.asarray(wo)))[:, 0]
        ref = np.array([_ray_cast_reference(a, b, 0.3, 0.6, 20.0, d, h) for a, b in zip(wi, wo, strict=True)])
        # the midpoint rule's error is O(1/m) at the visibility edges: ~1e-4 at m = 20000
        np.testing.assert_allclose(ours, ref, rtol=1e-3)


@pytest.mark.parametrize("d,h", [GEOMETRIES[0], GEOMETRIES[3], GEOMETRIES[4]])
def test_nonnegative_and_reciprocal(d, h):
    m = brdf.PoulinFournier(0.2, 0.7, 30.0, d, h)
    wi, wo = brdf.check.random_pairs(jax.random.PRNGKey(1), 4096)
    ei, eo = edge_case_pairs(jax.random.PRNGKey(2), 1024)
    wi, wo = jnp.concatenate([wi, ei]), jnp.concatenate([wo, eo])
    assert float(brdf.check.min_value(m, wi, wo)) >= 0
    # the lit-and-visible set and the integrand are symmetric in wi and wo, and so
    # are the quadrature panels: reciprocal to float64 rounding
    assert float(brdf.check.reciprocity_error(m, wi, wo)) < 1e-12


def _rotate(w, phi):
    c, s = np.cos(phi), np.sin(phi)
    return jnp.stack([c * w[:, 0] - s * w[:, 1], s * w[:, 0] + c * w[:, 1], w[:, 2]], -1)


def test_anisotropic_and_symmetric_under_half_turn():
    m = brdf.PoulinFournier(0.1, 0.8, 20.0, 0.5, 1.0)
    wi, wo = brdf.check.random_pairs(jax.random.PRNGKey(4), 512)
    f = ev_pairs(m, wi, wo)
    f_quarter = ev_pairs(m, _rotate(wi, np.pi / 2), _rotate(wo, np.pi / 2))
    f_half = ev_pairs(m, _rotate(wi, np.pi), _rotate(wo, np.pi))
    # anisotropic: a quarter turn about the normal changes f_r by a lot
    assert float(jnp.max(jnp.abs(f_quarter - f) / f)) > 0.5
    # the cylinders are mirror-symmetric in x and y: phi -> phi + pi leaves f_r
    # unchanged (to rounding: the rotated directions are rounded)
    assert_close(f_half, f, rtol=1e-12, atol=0)
    # a specular highlight: along the cylinders (both in the x-z plane) the mirror
    # pair is bright; across them (y-z plane) the cylinders spread it out
    along = ev_pairs(m, from_cos([0.7], [0.0]), from_cos([0.7], [np.pi]))
    across = ev_pairs(m, from_cos([0.7], [np.pi / 2]), from_cos([0.7], [-np.pi / 2]))
    assert float(along[0, 0]) > 2 * float(across[0, 0])


def test_wide_spacing_and_flat_cylinders_give_flat_phong():
    wi, wo = brdf.check.random_pairs(jax.random.PRNGKey(6), 2048)
    flat = ev_pairs(brdf.ModifiedPhong(0.3, 0.6, 20.0), wi, wo)
    # the caps occupy 2 / (2 + d) of the period, and their shadow on the base
    # reaches ~ 1 / cos_theta (1e4 at the smallest cos of these pairs): 1e-8 of
    # the period at d = 1e12
    wide = ev_pairs(brdf.PoulinFournier(0.3, 0.6, 20.0, 1e12, 1.0), wi, wo)
    assert_close(wide, flat, rtol=1e-6, atol=0)
    # h at its floor 1e-6: normals within t_max = 1.4e-3 rad of z; the lobe
    # (exponent 20) changes by ~ exponent * t_max^2 ~ 4e-5 relative. Directions
    # closer to the horizon than the slopes (cos < ~1e-3) are shadowed: excluded
    keep = (wi[:, 2] > 0.05) & (wo[:, 2] > 0.05)
    low = ev_pairs(brdf.PoulinFournier(0.3, 0.6, 20.0, 0.0, brdf._poulin_fournier.H_MIN), wi, wo)
    assert_close(low[keep], flat[keep], rtol=2e-4, atol=0)


@pytest.mark.parametrize("d,h", GEOMETRIES)
def test_diffuse_closed_form_along_the_cylinders(d, h):
    # wi, wo in the x-z plane project onto the normal of the cross-section: no
    # shadowing, and f_r = rho_d/pi (t_max + sin t_max cos t_max + d) / (2 sin t_max + d)
    m = brdf.PoulinFournier(0.8, 0.0, 10.0, d, h)
    wi = from_cos(np.array([0.9, 0.2, 1e-3]), np.array([0.0, np.pi, 0.0]))
    wo = from_cos(np.array([0.5, 0.7, 0.3]), np.array([np.pi, np.pi, 0.0]))
    t_max = np.arccos(1 - h)
    expect = 0.8 / np.pi * (t_max + np.sin(t_max) * np.cos(t_max) + d) / (2 * np.sin(t_max) + d)
    assert_close(ev_pairs(m, wi, wo)[:, 0], np.full(3, expect), rtol=1e-12, atol=0)


@pytest.mark.parametrize("d,h", [(0.0, 1.0), (0.5, 0.5), (3.0, 0.2)])
def test_albedo_at_most_rho_d_plus_rho_s(d, h):
    # every point reflects at most rho_d + rho_s of what it receives, the lit
    # projected width of a period is exactly P cos_i, and masking only removes
    # light: the albedo is <= rho_d + rho_s (= 0.95 here)
    m = brdf.PoulinFournier(0.15, 0.8, 10.0, d, h)
    a_max, _ = brdf.check.max_albedo(m, n_incident=12, n_azimuth=4, n_theta=24, n_phi=48)
    assert 0.2 < float(a_max) <= 0.95, float(a_max)


def test_albedo_of_white_diffuse_cylinders_at_normal_incidence():
    # rho_d = 1, contiguous half cylinders, light from the normal: every cap point
    # is lit, and the energy lost is the masking of the light that leaves each
    # point towards its neighbour, so the albedo is < 1 but close to it
    m = brdf.PoulinFournier(1.0, 0.0, 1.0, 0.0, 1.0)
    a = brdf.check.directional_albedo(m, jnp.asarray([[0.0, 0.0, 1.0]]), over="wo", n_theta=48, n_phi=96)
    assert 0.8 < float(a[0, 0]) < 1.0, float(a[0, 0])


def test_quadrature_error_against_ten_times_the_nodes(monkeypatch):
    wi, wo = brdf.check.random_pairs(jax.random.PRNGKey(8), 2000)
    mirror = jnp.concatenate([-wo[:, :2], wo[:, 2:]], -1)
    near = mirror + 0.05 * jax.random.normal(jax.random.PRNGKey(9), wo.shape)
    near = jnp.concatenate([near[:, :2], jnp.abs(near[:, 2:]) + 1e-3], -1)
    near = near / jnp.linalg.norm(near, axis=-1, keepdims=True)
    wi, wo = jnp.concatenate([wi, near]), jnp.concatenate([wo, wo])
    # N_NODES is read when the model is traced: one program per node count, each
    # compiled once (fresh jits, so the fine one cannot reuse the coarse trace) and
    # reused for the three exponents (parameters are traced, not baked in)
    coarse_fn = fjit(lambda m, a, b: jax.vmap(m)(a, b))
    fine_fn = fjit(lambda m, a, b: jax.vmap(m)(a, b))
    for n in (1.0, 100.0, 1e4):
        m = brdf.PoulinFournier(0.0, 1.0, n, 0.5, 0.5)
        coarse = coarse_fn(m, wi, wo)
        monkeypatch.setattr(pf, "N_NODES", 10 * pf.N_NODES)
        fine = fine_fn(m, wi, wo)
        monkeypatch.undo()
        scale = jnp.maximum(fine, 1e-6 * jnp.max(fine))
        # measured <= 4e-5 (docs/brdf.md); 1e-4 leaves room across jaxlib versions
        assert float(jnp.max(jnp.abs(coarse - fine) / scale)) < 1e-4, n


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_finite_values_and_gradients_at_edges(dtype):
    wi, wo = edge_case_pairs(jax.random.PRNGKey(10), 2048, dtype)
    ei, eo = edge_directions(dtype)
    wi, wo = jnp.concatenate([wi, ei]), jnp.concatenate([wo, eo])
    # the extremes: exponent at 1e4 and 0, height below its floor
    for params in [(0.2, 0.7, 1e4, 0.0, 1.0), (0.5, 0.5, 1.0, 0.0, 1e-9), (0.1, 0.9, 0.0, 0.0, 0.5)]:
        m = brdf.PoulinFournier(*[jnp.asarray(p, dtype) for p in params])
        assert brdf.check.stability(m, wi, wo) == {
            "value": True, "grad_directions": True, "grad_params": True, "nonnegative": True}, params


def test_wi_equals_wo_and_grazing_values():
    m = brdf.PoulinFournier(0.2, 0.7, 30.0, 0.5, 1.0)
    w = from_cos(np.array([1.0, 0.5, 1e-7, 1e-7]), np.array([0.0, 0.3, 0.0, np.pi / 2]))
    f = ev_pairs(m, w, w)
    assert_finite(f)
    assert float(jnp.min(f)) > 0  # wi = wo is lit and visible wherever it faces
    below = jnp.asarray([[0.6, 0.0, -0.8]])
    assert float(ev_pairs(m, below, w[:1])[0, 0]) == 0.0


def test_finite_difference_gradients():
    wi = from_cos(np.array([0.6, 0.3]), np.array([0.4, 2.0]))
    wo = from_cos(np.array([0.5, 0.8]), np.array([3.3, 5.0]))
    p0 = jnp.asarray([0.2, 0.7, 15.0, 0.6, 0.7])

    def total(p):
        return jnp.sum(jax.vmap(brdf.PoulinFournier(*p))(wi, wo))

    eps = 1e-6
    steps = eps * np.eye(5)
    # one program: the gradient at p0 and total at the 10 shifted points
    g, up, down = fjit(lambda p, s: (jax.grad(total)(p), jax.vmap(total)(p[None] + s),
                                     jax.vmap(total)(p[None] - s)))(p0, steps)
    fd = (np.asarray(up) - np.asarray(down)) / (2 * eps)
    # central differences in float64: truncation ~ eps^2 f''' and rounding ~ 1e-16 / eps
    assert_close(g, fd, rtol=1e-6, atol=1e-8)


def test_jit_vmap_eager_agree_and_texture_parameters():
    wi, wo = brdf.check.random_pairs(jax.random.PRNGKey(12), 64)
    r = jax.random.uniform(jax.random.PRNGKey(13), (64, 1))
    m = brdf.PoulinFournier(0.1 + 0.2 * r, jnp.full((64, 3), 0.6), 10 + 50 * r, 2 * r, 0.2 + 0.8 * r)
    call = jax.jit(lambda m, a, b: m(a, b))
    batched = m(wi, wo)  # eager
    jitted = call(m, wi, wo)
    one = jax.tree_util.tree_map(lambda x: x[5], m)
    assert batched.shape == (64, 3)
    assert_close(jitted, batched, rtol=1e-12, atol=0)
    # one texel's material on unbatched [3] directions (jitted: the eager path is the batched call's)
    assert_close(call(one, wi[5], wo[5]), batched[5], rtol=1e-12, atol=0)


def test_fittable_round_trip_and_bad_parameters():
    m = brdf.PoulinFournier(0.2, 0.7, 30.0, 0.5, 0.4)
    specs = m.fittable()
    assert set(specs) == {"rho_d", "rho_s", "exponent", "spacing", "height"}
    vals = brdf.get_params(m)
    u = {k: brdf.to_unconstrained(specs[k], v) for k, v in vals.items()}
    back = brdf.set_params(m, {k: brdf.from_unconstrained(specs[k], v) for k, v in u.items()})
    for k in vals:
        assert_close(brdf.get_params(back)[k], vals[k], rtol=1e-6, atol=0)
    for bad in (dict(spacing=-1.0), dict(height=0.0), dict(height=1.5), dict(exponent=float("nan"))):
        kw = dict(rho_d=0.2, rho_s=0.7, exponent=30.0, spacing=0.5, height=0.4) | bad
        with pytest.raises(ValueError, match="PoulinFournier"):
            brdf.PoulinFournier(**kw)

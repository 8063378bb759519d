"""The sparse surface diffusion operator: energy, symmetry, convergence, gradients,
chunking, per-sample profiles, and no seam on a UV-seamed mesh."""

import jax.numpy as jnp
import numpy as np
import pytest

import skin_bssrdf as sb
from tests.helpers import REFUSED, assert_close, assert_finite, fjit, grad_and_central_differences
from tests.scenes import texel_grid

_apply = fjit(lambda ops, profile, E, normalize=False: ops.apply(profile, E, normalize=normalize),
              static_argnames="normalize")

# A short-range material (r99 ~ 2.4 mm) keeps the neighbour lists small.
PROFILE = sb.Dipole(jnp.array([0.5, 0.9]), jnp.array([2.0, 2.5]), 1.3)
RADIUS = sb.operator_radius(PROFILE)


@pytest.fixture(scope="module")
def grid():
    pos, area, _ = texel_grid(36, 0.2)
    return pos, area, sb.DiffusionOperator.build(pos, area, RADIUS)


def _interior(pos, margin):
    lo, hi = pos.min(0), pos.max(0)
    return np.all((pos[:, :2] > lo[:2] + margin) & (pos[:, :2] < hi[:2] - margin), axis=1)


def test_energy_conservation_and_reported_tail(grid):
    pos, area, ops = grid
    E = jnp.full((pos.shape[0], 2), 2.0)
    tail = ops.tail(PROFILE)
    kept = PROFILE.total() - tail
    assert_close(tail, PROFILE.total() - PROFILE.cumulative(RADIUS))
    # RADIUS is the 99 % radius of the widest channel: it loses 1 %, the other less
    frac = np.asarray(tail / PROFILE.total())
    assert_close(frac.max(), 0.01, rtol=1e-9)
    assert frac.min() < 0.01
    # raw weights: uniform irradiance in, (total - tail) x it out, up to the quadrature error of
    # the sum at spacing 0.2 mm (1.4 % for this profile, whose peak width 1/sigma_t' is 0.3-0.4 mm)
    M = _apply(ops, PROFILE, E)
    inner = _interior(pos, RADIUS)
    assert inner.sum() > 0
    assert_close(M[inner], jnp.broadcast_to(2 * kept, M[inner].shape), rtol=0.02, atol=0)
    # normalised: exact everywhere, the open border included
    Mn = _apply(ops, PROFILE, E, normalize=True)
    assert_close(Mn, jnp.broadcast_to(2 * kept, Mn.shape), rtol=1e-12)
    # captured = row sums: smaller at the border (neighbours missing), which normalisation restores
    cap = np.asarray(ops.captured(PROFILE))
    assert cap[0, 0] < 0.7 * cap[inner][0, 0]


def test_symmetric_for_equal_areas(grid):
    pos, area, ops = grid
    w, w_self = ops.row_weights(PROFILE)
    P = pos.shape[0]
    W = np.zeros((P, P))
    rows = np.repeat(np.arange(P)[:, None], w.shape[1], axis=1)
    np.add.at(W, (rows, np.asarray(ops.index)), np.asarray(w[..., 1]))
    W[np.arange(P), np.arange(P)] += np.asarray(w_self[:, 1])
    assert_close(W, W.T, rtol=0, atol=1e-15)
    assert W.max() > 0


@pytest.mark.parametrize(
    "profile, bound",
    # Burley's 1/r singularity converges at first order (4.3, 2.6, 1.4 %); the dipole faster
    [(PROFILE, 0.01), (sb.Burley(jnp.array([0.5, 0.3]), jnp.array([0.3, 0.2])), 0.02)],
    ids=["dipole", "burley"],
)
def test_converges_as_spacing_shrinks(profile, bound):
    # exitance at the centre of a patch under uniform light against the exact (total - tail);
    # only the centre is a receiver, every sample of the patch a source
    radius = sb.operator_radius(profile)
    exact = np.asarray(profile.cumulative(radius))
    errs = []
    for h in (0.4, 0.2, 0.1):
        n = 2 * int(np.ceil(radius / h)) + 3
        pos, area, _ = texel_grid(n, h)
        c = (n // 2) * n + n // 2
        ops = sb.DiffusionOperator.build(pos, area, radius, receivers=np.array([c]))
        M = np.asarray(_apply(ops, profile, jnp.ones((pos.shape[0], 2))))
        assert M.shape == (1, 2)
        errs.append(np.max(np.abs(M[0] - exact) / exact))
    assert errs[2] < errs[1] < errs[0], errs
    assert errs[2] < bound, errs


def test_gradient_wrt_profile_matches_finite_differences():
    pos, area, _ = texel_grid(12, 0.3)
    ops = sb.DiffusionOperator.build(pos, area, 1.5, chunk=37)
    E = jnp.asarray(np.random.default_rng(0).uniform(0.5, 2.0, (pos.shape[0], 2)))

    def f(x):
        p = sb.Dipole(x[:2], x[2:4], x[4])
        return jnp.sum(ops.apply(p, E) * jnp.arange(pos.shape[0], dtype=E.dtype)[:, None])

    x = jnp.array([0.5, 0.9, 2.0, 2.5, 1.3])
    h = 1e-6
    g, fd = grad_and_central_differences(f, x, h)
    assert_close(g, fd, rtol=1e-6, atol=1e-8)  # central differences, float64


def test_chunking_and_per_sample_profiles_agree(grid):
    pos, area, ops = grid
    P = pos.shape[0]
    E = jnp.asarray(np.random.default_rng(1).uniform(0, 1, (P, 2)))
    small = sb.DiffusionOperator.build(pos, area, RADIUS, chunk=97)  # P is not a multiple of 97
    per = sb.Dipole(jnp.tile(PROFILE.sigma_a, (P, 1)), jnp.tile(PROFILE.sigma_s_prime, (P, 1)), 1.3)
    # a texture of parameters: each receiving sample uses its own profile
    sa = jnp.where(jnp.arange(P)[:, None] < P // 2, 0.5, 0.8) * jnp.ones((P, 2))
    profiles = (PROFILE, per, sb.Dipole(sa, 2.0, 1.3), sb.Dipole(jnp.full(2, 0.5), 2.0, 1.3),
                sb.Dipole(jnp.full(2, 0.8), 2.0, 1.3))

    # every apply in one program (eager, each compiled its chunk loop on its own)
    @fjit
    def applied(ops, small, profiles, E):
        one, per, mixed, lo, hi = profiles
        return (ops.apply(one, E), small.apply(one, E), ops.apply(per, E), ops.apply(mixed, E), ops.apply(lo, E),
                ops.apply(hi, E), ops.apply(per, E, normalize=True))

    ref, chunked, per_sample, mixed, lo, hi, normalized = applied(ops, small, profiles, E)
    assert_close(chunked, ref, rtol=1e-12)
    assert_close(per_sample, ref, rtol=1e-12)
    assert_close(mixed[: P // 2], lo[: P // 2], rtol=1e-12)
    assert_close(mixed[P // 2 :], hi[P // 2 :], rtol=1e-12)
    assert_finite(normalized)


def test_max_neighbours_keeps_the_nearest(grid):
    pos, area, ops = grid
    few = sb.DiffusionOperator.build(pos, area, RADIUS, max_neighbours=8)
    assert few.index.shape[1] == 8
    d = np.asarray(few.distance)
    assert np.all(d[:, :-1] <= d[:, 1:] + 1e-12)  # nearest first
    assert np.all(np.asarray(few.captured(PROFILE)) < np.asarray(ops.captured(PROFILE)))


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: sb.DiffusionOperator.build(np.zeros((4, 2)), np.ones(4), 1.0), "positions"),
        (lambda: sb.DiffusionOperator.build(np.zeros((4, 3)), -np.ones(4), 1.0), "areas"),
        (lambda: sb.DiffusionOperator.build(np.zeros((4, 3)), np.ones(3), 1.0), "areas"),
        (lambda: sb.DiffusionOperator.build(np.zeros((4, 3)), np.ones(4), 0.0), "radius_mm"),
        (lambda: sb.DiffusionOperator.build(np.full((4, 3), np.nan), np.ones(4), 1.0), "positions"),
    ],
)
def test_build_rejects_bad_input(call, match):
    with pytest.raises(REFUSED, match=match):
        call()


def test_apply_rejects_bad_shapes(grid):
    pos, area, ops = grid
    with pytest.raises(ValueError, match="irradiance"):
        ops.apply(PROFILE, jnp.ones((3, 2)))
    with pytest.raises(ValueError, match="batch shape"):
        ops.apply(sb.Dipole(jnp.ones((5, 2)), 1.0, 1.3), jnp.ones((pos.shape[0], 2)))


def test_no_seam_on_uv_seamed_head(shared_data):
    stage = pytest.importorskip("stage")
    mesh = stage.load_mesh(shared_data / "meshes" / "lee_perry_smith_head.glb", scale=stage.HEAD_SCALE_MM, center=True)
    surf = stage.texel_samples(mesh, 96)
    pos = np.asarray(surf.position, np.float64)
    area = np.asarray(surf.area, np.float64)
    ti = np.asarray(surf.texel_index)
    W = surf.resolution[1]
    tex = np.stack([ti // W, ti % W], -1)
    # a wide profile (sigma 2-8 mm, several texels at this resolution) and irradiance smooth in 3-D
    prof = sb.SumOfGaussians(jnp.full((3, 1), 0.3), jnp.array([4.0, 16.0, 64.0]))
    E = jnp.asarray(1 + 0.5 * np.sin(2 * np.pi * pos[:, :1] / 40.0))
    radius = sb.operator_radius(prof)
    M = np.asarray(_apply(sb.DiffusionOperator.build(pos, area, radius), prof, E, normalize=True))[:, 0]
    T = np.asarray(sb.TextureSpaceDiffusion.build(ti, surf.resolution, pos).apply(prof, E))[:, 0]
    # neighbours in 3-D (within one texel spacing) far apart in the texture: across a UV seam
    from scipy.spatial import cKDTree

    spacing = float(np.sqrt(np.median(area)))
    pairs = cKDTree(pos).query_pairs(spacing, output_type="ndarray")
    far = np.max(np.abs(tex[pairs[:, 0]] - tex[pairs[:, 1]]), axis=1) > 3
    seam, ordinary = pairs[far], pairs[~far]
    assert len(seam) > 20, "the head's atlas has seams"

    def slope99(X, p):  # 99th percentile of |dM| / distance over pairs
        d = np.linalg.norm(pos[p[:, 0]] - pos[p[:, 1]], axis=1)
        return np.percentile(np.abs(X[p[:, 0]] - X[p[:, 1]]) / np.maximum(d, 1e-3), 99)

    # 3-D kernel: across seams the exitance changes no faster than between texture neighbours
    assert slope99(M, seam) <= 1.5 * slope99(M, ordinary)
    # the same statistic does see a seam: texture-space blurs cannot cross one (> 3x here)
    assert slope99(T, seam) > 3 * slope99(T, ordinary)

"""NaN sweep of the lat-long lookups: every public function of
relight/envmap/_latlong.py and _sampling.py (found from their ``__all__``, so a new
one fails here until it has a case) gives finite values and finite gradients, in
float32 and float64, at the poles, on the seam (phi = 0 / 2 pi, the map's left and
right edges, +z), next to both, for unnormalised (1e-3, 1e3, 1e-20, 1e20) and
zero-length directions, and at pixel-centre and random directions. Where a value
is known it is checked too: the poles and the zero vector map to v = 0 / 1, the
lookup does not depend on the direction's length, the seam's two sides agree.
Each function's value and gradient are one jitted program (as the renderers call
them; the library's own lookups are jitted), compiled once per function and dtype."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from relight.envmap import (
    EnvMap,
    _latlong,
    _sampling,
    direction_to_latlong,
    envmap_integral,
    envmap_irradiance,
    envmap_pdf,
    envmap_sampler,
    latlong_directions,
    latlong_solid_angles,
    rotate_envmap,
    rotation_matrix,
    sample_envmap,
    sample_latlong,
)

DTYPES = (jnp.float32, jnp.float64)
H, W = 8, 16
SCALES = (1.0, 1e-3, 1e3, 1e-20, 1e20)


def _directions() -> tuple[np.ndarray, list[str]]:
    """Unit directions [N, 3] (float64) at the edges of the lat-long map, and their kinds."""
    rng = np.random.default_rng(0)
    d, kind = [], []

    def add(v, k):
        v = np.atleast_2d(np.asarray(v, float))
        d.append(v)
        kind.extend([k] * v.shape[0])

    add([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [-0.0, 1.0, -0.0], [0.0, -1.0, -0.0]], "pole")
    for eps in (1e-7, 1e-20, 1e-40):
        for sx, sz in ((1, 0), (0, 1), (-1, 0), (0, -1), (1, 1)):
            for y in (1.0, -1.0):
                add([sx * eps, y, sz * eps], "next to a pole")
    # the seam: phi = +-pi, d = (+-0 or +-tiny, y, +z), in the upper, lower and equatorial bands
    for y in (0.0, 0.7, -0.7):
        for x in (0.0, -0.0, 1e-8, -1e-8, 1e-30, -1e-30):
            add([x, y, np.sqrt(1 - y * y)], "seam")
    add([0.0, 0.0, -1.0], "centre")
    add(np.asarray(latlong_directions(H, W, jnp.float64)).reshape(-1, 3)[::7], "pixel centre")
    r = rng.normal(size=(32, 3))
    add(r / np.linalg.norm(r, axis=-1, keepdims=True), "random")
    d = np.concatenate(d)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    return d, kind


def _all_directions():
    d, kind = _directions()
    out = [d * s for s in SCALES] + [np.zeros((2, 3)), np.array([[-0.0, -0.0, -0.0], [0.0, -0.0, 0.0]])]
    kinds = [f"{k} x{s:g}" for s in SCALES for k in kind] + ["zero"] * 4
    return np.concatenate(out), kinds


def _same_direction_lanes(d, dtype):
    """Masks [len(SCALES) - 1, n]: lanes whose scaled copy represents the same direction as the unit
    vector in ``dtype`` (every non-zero component of both is a normal number: denormals are
    flushed to zero on the CPU, which turns a direction next to a pole into the pole)."""
    n = len(_directions()[1])
    tiny = float(jnp.finfo(dtype).tiny)

    def normal(x):
        return np.all((x == 0) | (np.abs(x) >= tiny), axis=-1)

    return [normal(d[:n]) & normal(d[i * n:(i + 1) * n]) for i in range(1, len(SCALES))]


def _env(dtype, seed=1):
    rng = np.random.default_rng(seed)
    return EnvMap(jnp.asarray(rng.uniform(0.0, 4.0, (H, W, 3)), dtype))


def _bad(tree):
    return [jax.tree_util.keystr(p) for p, x in jax.tree_util.tree_leaves_with_path(tree)
            if jnp.issubdtype(jnp.asarray(x).dtype, jnp.inexact) and not np.all(np.isfinite(np.asarray(x)))]


def _check(name, out, grads):
    bad = _bad(out) + [f"d{p}" for p in _bad(grads)]
    assert not bad, f"{name}: non-finite {bad}"


@functools.cache
def _compiled_value_and_grad(f, n_args):
    """One jitted program per function, with XLA's default options: the library's lookups are jitted with them,
    and brdf.check.FAST_COMPILE's emitters are not bit-identical (sample_latlong's float32 length independence
    fails under them)."""

    def total(*a):
        out = f(*a)
        leaves = [x for x in jax.tree_util.tree_leaves(out) if jnp.issubdtype(x.dtype, jnp.inexact)]
        return sum(jnp.sum(x) for x in leaves), out

    return jax.jit(jax.grad(total, argnums=tuple(range(n_args)), has_aux=True))


def _value_and_grad(f, *args):
    """f's output, and the gradient of the sum of its float outputs w.r.t. every float leaf of args."""
    grads, out = _compiled_value_and_grad(f, len(args))(*args)
    return out, grads


# ---------------------------------------------------------------------------
# One case per public function


def case_direction_to_latlong(dtype):
    d, kinds = _all_directions()
    dj = jnp.asarray(d, dtype)
    (v, u), (g,) = _value_and_grad(direction_to_latlong, dj)
    _check("direction_to_latlong", (v, u), g)
    v, u = np.asarray(v), np.asarray(u)
    assert np.all((v >= 0) & (v <= 1)) and np.all((u >= 0) & (u < 1))
    # poles and the zero vector: v = 0 (zenith) or 1 (nadir), exactly
    pole = np.array([k.startswith("pole") for k in kinds])
    assert np.all(v[pole & (d[:, 1] > 0)] == 0) and np.all(v[pole & (d[:, 1] < 0)] == 1)
    assert np.all(v[np.array([k == "zero" for k in kinds])] == 0)
    # independent of the length: every scaled copy gives the unit direction's (v, u)
    n = len(_directions()[1])
    tol = 4 * float(jnp.finfo(dtype).eps)
    for i, same in enumerate(_same_direction_lanes(d, dtype), start=1):
        np.testing.assert_allclose(v[i * n:(i + 1) * n][same], v[:n][same], atol=tol)
        du = np.abs(u[i * n:(i + 1) * n] - u[:n])[same]
        assert np.all(np.minimum(du, 1 - du) <= tol), f"scale {SCALES[i]}"  # u is periodic
    # the gradient of v at the exact poles is 0 (the polar angle's subgradient there)
    assert np.all(np.asarray(g)[pole] == 0)


def case_sample_latlong(dtype, method="bilinear"):
    env = _env(dtype)
    d, kinds = _all_directions()
    dj = jnp.asarray(d, dtype)
    out, grads = _value_and_grad(functools.partial(sample_latlong, method=method), env.radiance, dj)
    _check(f"sample_latlong({method})", out, grads)
    out = np.asarray(out)
    # the length of d does not matter (same pixel weights up to rounding)
    n = len(_directions()[1])
    for i, same in enumerate(_same_direction_lanes(d, dtype), start=1):
        np.testing.assert_allclose(out[i * n:(i + 1) * n][same], out[:n][same],
                                   rtol=1e-4 if dtype == jnp.float32 else 1e-10)
    if method == "nearest":
        return  # the seam is the edge between two texels: nearest jumps there
    # the two sides of the seam look up the same texels: their values agree to first order in the offset
    seam = [i for i, k in enumerate(kinds[:n]) if k == "seam x1"]
    s = out[seam].reshape(3, 6, 3)  # bands x (0, -0, 1e-8, -1e-8, 1e-30, -1e-30) x channels
    np.testing.assert_allclose(s, np.broadcast_to(s[:, :1], s.shape), rtol=1e-5 if dtype == jnp.float32 else 1e-7)


def case_sample_latlong_nearest(dtype):
    case_sample_latlong(dtype, "nearest")


def case_rotation_matrix(dtype):
    axes = jnp.asarray([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1e-20, 0.0, 0.0], [3.0, -4.0, 12.0], [1e20, 1e20, 0.0]],
                       dtype)
    angles = jnp.asarray([0.0, np.pi, 1.0, -np.pi / 2, 2 * np.pi], dtype)
    out, grads = _value_and_grad(jax.vmap(rotation_matrix), axes, angles)
    _check("rotation_matrix", out, grads)
    np.testing.assert_allclose(np.asarray(out[0]), np.eye(3), atol=0)  # a zero axis gives the identity
    # the axis' length does not matter, however small or large
    tol = 8 * float(jnp.finfo(dtype).eps)
    np.testing.assert_allclose(out[2], rotation_matrix(jnp.asarray([1.0, 0, 0], dtype), angles[2]), atol=tol)
    np.testing.assert_allclose(out[4], rotation_matrix(jnp.asarray([1.0, 1.0, 0], dtype), angles[4]), atol=tol)


def case_rotate_envmap(dtype):
    env = _env(dtype)
    rotated = lambda e, rr: rotate_envmap(e, rr).radiance  # noqa: E731  (one object: compiled once)
    for axis, angle in (([1.0, 0.0, 0.0], np.pi / 2), ([0.0, 0.0, 1.0], np.pi / 2), ([0.0, 1.0, 0.0], 0.0),
                        ([0.0, 0.0, 0.0], 1.0)):
        r = rotation_matrix(jnp.asarray(axis, dtype), jnp.asarray(angle, dtype))
        out, grads = _value_and_grad(rotated, env, r)
        _check(f"rotate_envmap about {axis}", out, grads)


def case_envmap_integral(dtype):
    for env in (_env(dtype), EnvMap(jnp.zeros((H, W, 3), dtype))):
        out, grads = _value_and_grad(envmap_integral, env)
        _check("envmap_integral", out, grads)


def _irradiance_64(e, n):
    return envmap_irradiance(e, n, chunk=64)


def case_envmap_irradiance(dtype):
    d, _ = _all_directions()
    out, grads = _value_and_grad(_irradiance_64, _env(dtype), jnp.asarray(d, dtype))
    _check("envmap_irradiance", out, grads)


def case_latlong_directions(dtype):
    for h in (1, 2, H):
        d = latlong_directions(h, 2 * h, dtype)
        _check("latlong_directions", d, ())
        np.testing.assert_allclose(np.linalg.norm(np.asarray(d, float), axis=-1), 1.0, rtol=1e-6)


def case_latlong_solid_angles(dtype):
    for h in (1, 2, H):
        a = latlong_solid_angles(h, 2 * h, dtype)
        _check("latlong_solid_angles", a, ())
        np.testing.assert_allclose(float(jnp.sum(a)), 4 * np.pi, rtol=1e-5)


def _maps(dtype):
    """A random map, a black one (uniform fallback), one with black rows (the poles) and one bright texel."""
    rad = np.asarray(_env(dtype).radiance)
    rows = rad.copy()
    rows[[0, -1]] = 0.0
    spot = np.zeros_like(rad)
    spot[0, 3] = 1e4
    return [jnp.asarray(x, dtype) for x in (rad, np.zeros_like(rad), rows, spot)]


def case_envmap_sampler(dtype):
    build = lambda r: envmap_sampler(EnvMap(r))  # noqa: E731  (one object: compiled once)
    for rad in _maps(dtype):
        out, grads = _value_and_grad(build, rad)
        _check("envmap_sampler", out, grads)


def _uniforms(dtype):
    one = float(1 - jnp.finfo(dtype).eps)
    edges = [0.0, one, 0.5, 1.0 / H, 1.0 / W, 1e-30]
    u = np.array([[a, b] for a in edges for b in edges])
    return jnp.asarray(np.concatenate([u, np.random.default_rng(2).uniform(size=(64, 2))]), dtype)


def case_sample_envmap(dtype):
    for rad in _maps(dtype):
        sampler = envmap_sampler(EnvMap(rad))
        out, grads = _value_and_grad(sample_envmap, sampler, _uniforms(dtype))
        _check("sample_envmap", out, grads)
        d, pdf = np.asarray(out[0], float), np.asarray(out[1])
        np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, rtol=1e-5)  # unit directions, poles included
        assert np.all(pdf >= 0)


def case_envmap_pdf(dtype):
    d, _ = _all_directions()
    for rad in _maps(dtype):
        sampler = envmap_sampler(EnvMap(rad))
        out, grads = _value_and_grad(envmap_pdf, sampler, jnp.asarray(d, dtype))
        _check("envmap_pdf", out, grads)
        assert np.all(np.asarray(out) >= 0)


CASES = {
    "direction_to_latlong": case_direction_to_latlong,
    "sample_latlong": case_sample_latlong,
    "sample_latlong_nearest": case_sample_latlong_nearest,
    "rotation_matrix": case_rotation_matrix,
    "rotate_envmap": case_rotate_envmap,
    "envmap_integral": case_envmap_integral,
    "envmap_irradiance": case_envmap_irradiance,
    "latlong_directions": case_latlong_directions,
    "latlong_solid_angles": case_latlong_solid_angles,
    "envmap_sampler": case_envmap_sampler,
    "sample_envmap": case_sample_envmap,
    "envmap_pdf": case_envmap_pdf,
}
# Public names that are not lookups: the map's container (its constructor validates the shape) and the
# file reader (its guard against NaN/Inf radiance, check_radiance, is tested in test_envmap_latlong.py).
NOT_LOOKUPS = {"EnvMap", "EnvSampler", "load_envmap"}


def test_every_public_lookup_has_a_case():
    public = set(_latlong.__all__) | set(_sampling.__all__)
    missing = public - set(CASES) - NOT_LOOKUPS
    assert not missing, f"no NaN-sweep case for {sorted(missing)}"


@pytest.mark.parametrize("dtype", DTYPES, ids=lambda d: jnp.dtype(d).name)
@pytest.mark.parametrize("name", list(CASES))
def test_envmap_nan_sweep(name, dtype):
    CASES[name](dtype)

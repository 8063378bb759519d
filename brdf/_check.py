"""Property checks for any reflectance model with the common interface
``model(wi, wo) -> f_r``: reciprocity, non-negativity, directional albedo by
quadrature and by importance-sampled Monte Carlo (the white furnace test), the
maximum albedo over incident directions, and the edge-case direction pairs of
the stability sweeps.

The checks evaluate one material: the model's parameters must be 0-d or of
shape [C] (``jax.vmap`` a check over a texture of materials). Directions are
evaluated one at a time under ``jax.vmap``, so the model sees wi, wo of shape [3].
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray

from ._safe import safe_div
from ._sampling import pdf_cosine_hemisphere, sample_cosine_hemisphere

# Checks run once per model on moderate arrays: compile time dominates, so they
# are compiled with XLA's cheap settings (about 4x faster to compile than the
# default, measured on the all-model stability graph; arithmetic stays IEEE,
# there is no fast-math here).
FAST_COMPILE = {
    "xla_backend_optimization_level": 0,
    "xla_llvm_disable_expensive_passes": True,
    "xla_cpu_use_fusion_emitters": False,
}


def _fast_jit(fun):
    """Like equinox.filter_jit (array leaves traced, everything else static) but
    compiled with FAST_COMPILE."""
    cache = {}

    @functools.wraps(fun)
    def wrapped(*args):
        leaves, treedef = jax.tree_util.tree_flatten(args)
        if any(isinstance(x, jax.core.Tracer) for x in leaves):
            return fun(*args)  # already inside a transformation: inline, no nested compile
        is_arr = tuple(eqx.is_array(x) for x in leaves)
        static = tuple(None if a else x for x, a in zip(leaves, is_arr, strict=True))
        try:
            key = (treedef, is_arr, static)
            hash(key)
        except TypeError:  # unhashable static leaf: key by identity
            key = (treedef, is_arr, tuple(map(id, static)))
        if key not in cache:

            def inner(dyn):
                it = iter(dyn)
                full = [next(it) if a else x for x, a in zip(static, is_arr, strict=True)]
                return fun(*jax.tree_util.tree_unflatten(treedef, full))

            options = FAST_COMPILE if jax.default_backend() == "cpu" else None
            cache[key] = jax.jit(inner, compiler_options=options)
        return cache[key]([x for x, a in zip(leaves, is_arr, strict=True) if a])

    return wrapped


def _pairwise(model):
    """f over arrays of pairs [N, 3] x [N, 3] -> [N, C], one material."""
    return jax.vmap(lambda a, b: model(a, b))


def _as_dirs(w, dtype=None) -> Array:
    w = jnp.asarray(w, dtype=dtype)
    if w.ndim == 1:
        w = w[None]
    if w.ndim != 2 or w.shape[-1] != 3:
        raise ValueError(f"directions must have shape [3] or [M, 3], got {w.shape}")
    return w


def hemisphere_quadrature(
    n_theta: int = 64, n_phi: int = 64, breaks=(0.05, 0.15, 0.4), dtype=jnp.float64
) -> tuple[Float[Array, "N 3"], Float[Array, " N"]]:
    """Product quadrature over the upper hemisphere: composite Gauss-Legendre in
    theta (``n_theta`` nodes per panel between the theta ``breaks`` in radians,
    sorted, those outside (0, pi/2) ignored, so that narrow lobes near the normal
    are resolved) times the midpoint rule in phi
    (exponentially accurate for smooth periodic integrands).

    Returns unit directions [N, 3] and weights [N] in sr (sum(weights) = 2 pi).
    """
    if n_theta < 1 or n_phi < 1:
        raise ValueError(f"n_theta and n_phi must be >= 1, got {n_theta}, {n_phi}")
    b = np.unique(np.asarray(breaks, float))
    b = b[(b > 0) & (b < np.pi / 2)]  # breaks outside the open interval are dropped
    edges = np.concatenate([[0.0], b, [np.pi / 2]])
    x, w = np.polynomial.legendre.leggauss(n_theta)
    thetas, wts = [], []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        thetas.append(0.5 * (b - a) * x + 0.5 * (a + b))
        wts.append(0.5 * (b - a) * w)
    theta = np.concatenate(thetas)
    wt = np.concatenate(wts) * np.sin(theta)
    phi = (np.arange(n_phi) + 0.5) * (2 * np.pi / n_phi)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    dirs = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    weights = (wt[:, None] * np.full(n_phi, 2 * np.pi / n_phi)[None, :]).reshape(-1)
    return jnp.asarray(dirs, dtype), jnp.asarray(weights, dtype)


def _check_over(over):
    if over not in ("wi", "wo"):
        raise ValueError(f"over must be 'wi' or 'wo', got {over!r}")


def directional_albedo(
    model,
    w: Float[Array, " 3"] | Float[Array, "M 3"],
    n_theta: int = 64,
    n_phi: int = 64,
    breaks=(0.05, 0.15, 0.4),
    over: str = "wi",
) -> Float[Array, "M C"]:
    """Directional albedo by :func:`hemisphere_quadrature`, <= 1 for an
    energy-conserving model (white furnace):

    - ``over="wi"``: a(w) = integral f_r(wi, w) cos(theta_i) dwi (pbrt's rho(wo));
    - ``over="wo"``: a(w) = integral f_r(w, wo) cos(theta_o) dwo, the fraction of
      light arriving from w that is reflected.

    The two agree for reciprocal models; for Phong they do not.
    """
    _check_over(over)
    w = _as_dirs(w)
    dirs, weights = hemisphere_quadrature(n_theta, n_phi, breaks, dtype=w.dtype)
    return _albedo_quadrature(model, w, dirs, weights, over)


@_fast_jit
def _albedo_quadrature(model, w, dirs, weights, over):
    def one(w1):
        fixed = jnp.broadcast_to(w1, dirs.shape)
        vals = _pairwise(model)(dirs, fixed) if over == "wi" else _pairwise(model)(fixed, dirs)
        return jnp.sum(vals * (dirs[:, 2:3] * weights[:, None]), axis=0)

    return jax.lax.map(one, w)


def directional_albedo_mc(
    model, wo: Float[Array, " 3"] | Float[Array, "M 3"], key: PRNGKeyArray, n: int = 65536, sampler: str = "auto"
) -> tuple[Float[Array, "M C"], Float[Array, "M C"]]:
    """Directional albedo by importance-sampled Monte Carlo: the mean of
    f_r cos(theta_i) / pdf and its standard error, over ``n`` samples per wo.

    ``sampler``: ``"model"`` uses ``model.sample(wo, u) -> (wi, pdf)`` (e.g. GGX
    visible normals), ``"cosine"`` the cosine-weighted hemisphere, ``"auto"`` the
    model's own when it has one.
    """
    wo = _as_dirs(wo)
    if sampler == "auto":
        sampler = "model" if hasattr(model, "sample") else "cosine"
    if sampler not in ("model", "cosine"):
        raise ValueError(f"sampler must be 'auto', 'model' or 'cosine', got {sampler!r}")
    if n < 2:
        raise ValueError(f"n must be >= 2, got {n}")

    keys = jax.random.split(key, wo.shape[0])
    return _albedo_mc(model, wo, keys, n, sampler)


@_fast_jit
def _albedo_mc(model, wo, keys, n, sampler):
    def one(args):
        wo_1, k = args
        u = jax.random.uniform(k, (n, 2), dtype=wo.dtype)
        wos = jnp.broadcast_to(wo_1, (n, 3))
        if sampler == "model":
            wi, pdf = jax.vmap(lambda w, uu: model.sample(w, uu))(wos, u)
        else:
            wi = sample_cosine_hemisphere(u)
            pdf = pdf_cosine_hemisphere(wi)
        vals = _pairwise(model)(wi, wos) * jnp.maximum(wi[:, 2:3], 0.0)
        est = safe_div(vals, pdf)
        return jnp.mean(est, axis=0), jnp.std(est, axis=0) / np.sqrt(n)

    return jax.lax.map(one, (wo, keys))


def max_albedo(
    model, n_incident: int = 32, n_azimuth: int = 1, over: str = "wi", **quadrature
) -> tuple[Array, Array]:
    """The largest directional albedo over incident directions: theta on a
    Gauss-Chebyshev-like grid in (0, pi/2) (grazing included down to cos ~ 1e-3)
    times ``n_azimuth`` azimuths in [0, pi) (use > 1 for anisotropic models; the
    models here are symmetric under phi -> phi + pi).

    ``over`` and the quadrature keywords are those of :func:`directional_albedo`.
    Returns (max over directions and channels, the direction [3] where it occurs).
    """
    c = np.cos(0.5 * np.pi * (np.arange(n_incident) + 0.5) / n_incident)  # cos theta in (0, 1)
    phi = (np.arange(n_azimuth) + 0.5) * (np.pi / max(n_azimuth, 1))
    cc, pp = np.meshgrid(c, phi, indexing="ij")
    s = np.sqrt(1 - cc**2)
    wo = jnp.asarray(np.stack([s * np.cos(pp), s * np.sin(pp), cc], -1).reshape(-1, 3))
    a = directional_albedo(model, wo, over=over, **quadrature)
    per_dir = jnp.max(a, axis=-1)
    i = jnp.argmax(per_dir)
    return per_dir[i], wo[i]


def random_pairs(key: PRNGKeyArray, n: int, dtype=jnp.float64) -> tuple[Float[Array, "n 3"], Float[Array, "n 3"]]:
    """``n`` pairs of directions uniform over the upper hemisphere."""
    return _random_pairs(key, int(n), jnp.dtype(dtype))


@_fast_jit
def _random_pairs(key, n, dtype):
    k1, k2 = jax.random.split(key)

    def dirs(k):
        u = jax.random.uniform(k, (n, 2), dtype=dtype)
        z = u[:, 0:1]
        r = jnp.sqrt(1 - z * z)
        phi = 2 * jnp.pi * u[:, 1:2]
        return jnp.concatenate([r * jnp.cos(phi), r * jnp.sin(phi), z], -1)

    return dirs(k1), dirs(k2)


def edge_case_pairs(key: PRNGKeyArray, n: int, dtype=jnp.float64) -> tuple[Float[Array, "n 3"], Float[Array, "n 3"]]:
    """``n`` direction pairs for stability sweeps, mixing in equal parts: random
    pairs; grazing wi or wo (cos = 1e-7 and exactly 0); wi = wo; exact mirror
    pairs (wi = reflect(wo)); normal incidence on one or both sides; and both
    grazing. All vectors are unit length in ``dtype``."""
    ks = jax.random.split(key, 4)
    wi, wo = random_pairs(ks[0], n, dtype)
    kind = jax.random.randint(ks[1], (n, 1), 0, 8)
    phi = jax.random.uniform(ks[2], (n, 1), dtype=dtype) * 2 * jnp.pi
    graze_cos = jnp.where(jax.random.uniform(ks[3], (n, 1)) < 0.5, 1e-7, 0.0).astype(dtype)

    def grazing(c):
        s = jnp.sqrt(1 - c * c)
        return jnp.concatenate([s * jnp.cos(phi), s * jnp.sin(phi), c], -1)

    g = grazing(graze_cos)
    normal = jnp.broadcast_to(jnp.asarray([0.0, 0.0, 1.0], dtype), (n, 3))
    mirror = jnp.concatenate([-wo[:, :2], wo[:, 2:]], axis=-1)
    new_wi = jnp.select(
        [kind == 1, kind == 3, kind == 4, kind == 5, kind == 6, kind == 7],
        [g, wo, mirror, normal, normal, g],
        wi,
    )
    new_wo = jnp.select([kind == 2, kind == 6, kind == 7], [g, normal, grazing(graze_cos)[:, [1, 0, 2]]], wo)
    return new_wi, new_wo


@_fast_jit
def reciprocity_error(model, wi: Float[Array, "n 3"], wo: Float[Array, "n 3"]) -> Array:
    """max |f(wi, wo) - f(wo, wi)| / max(|f(wi, wo)|, |f(wo, wi)|, tiny) over the pairs
    and channels: 0 (up to rounding) for a reciprocal model."""
    f = _pairwise(model)
    a = f(wi, wo)
    b = f(wo, wi)
    scale = jnp.maximum(jnp.maximum(jnp.abs(a), jnp.abs(b)), jnp.finfo(a.dtype).tiny)
    return jnp.max(jnp.abs(a - b) / scale)


@_fast_jit
def min_value(model, wi: Float[Array, "n 3"], wo: Float[Array, "n 3"]) -> Array:
    """The smallest f_r over the pairs and channels: >= 0 for a physical model."""
    return jnp.min(_pairwise(model)(wi, wo))


@_fast_jit
def _values_and_grads(model, wi, wo, batched):
    params, static = eqx.partition(model, eqx.is_inexact_array)

    def total(p, a, b):
        m = eqx.combine(p, static)
        vals = m(a, b) if batched else _pairwise(m)(a, b)
        return jnp.sum(vals), vals

    grads, vals = jax.grad(total, argnums=(0, 1, 2), has_aux=True)(params, wi, wo)
    return vals, grads


def stability(model, wi: Float[Array, "n 3"], wo: Float[Array, "n 3"], batched: bool = False) -> dict[str, bool]:
    """Whether f_r and its gradients are finite over the pairs: ``"value"``,
    ``"grad_directions"`` (w.r.t. wi and wo) and ``"grad_params"`` (w.r.t. every
    floating-point array of the model), plus ``"nonnegative"``.

    ``batched=True`` calls ``model(wi, wo)`` on the whole [n, 3] arrays, so the
    model's parameters may be per pair ([n, 1] or [n, C]); otherwise one material
    is evaluated pair by pair under ``jax.vmap``.
    """
    vals, (gp, ga, gb) = _values_and_grads(model, wi, wo, batched)

    def finite(t):
        return bool(all(jnp.all(jnp.isfinite(x)) for x in jax.tree_util.tree_leaves(t)))

    return {
        "value": finite(vals),
        "grad_directions": finite((ga, gb)),
        "grad_params": finite(gp),
        "nonnegative": bool(jnp.all(vals >= 0)),
    }


def example_models(key: PRNGKeyArray, n: int, dtype=jnp.float64) -> dict:
    """One instance of every analytic model in the package, with parameters drawn
    per pair (shape [n, 1] or [n, 3], for directions [n, 3]) across their valid
    ranges: roughness log-uniform from the model's floor ALPHA_MIN to 1 (a tenth
    of the pairs exactly at the floor, a tenth exactly 1), exponents from 0 to
    1e4, albedos and Fresnel parameters across [0, 1] and typical metals.
    Used by the stability sweeps."""
    from . import (
        _beckmann,
        _cook_torrance,
        _diffuse,
        _distribution,
        _fresnel,
        _ggx,
        _lambert,
        _microfacet,
        _phong,
        _ward,
    )

    floor = _distribution.ALPHA_MIN
    ks = jax.random.split(key, 8)

    def rough(k):
        u = jax.random.uniform(k, (n, 1), dtype=dtype)
        a = jnp.exp(jnp.log(floor) * u)  # log-uniform in [floor, 1]
        a = jnp.where(u < 0.1, floor, a)
        return jnp.where(u > 0.9, 1.0, a).astype(dtype)

    def unit(k, c=1):
        return jax.random.uniform(k, (n, c), dtype=dtype)

    ax, ay = rough(ks[0]), rough(ks[1])
    rho = unit(ks[2], 3)
    rs = unit(ks[3])
    f0 = unit(ks[4])
    expo = jnp.exp(jnp.log(1e4) * unit(ks[5])) - 1.0  # [0, 1e4 - 1]
    eta = 0.05 + 3.0 * unit(ks[6], 3)
    kk = 5.0 * unit(ks[7], 3)
    sigma = (jnp.pi / 2) * unit(ks[5])
    mf = _microfacet.Microfacet
    return {
        "lambert": _lambert.Lambert(rho),
        "ggx_schlick_smith": mf(_ggx.GGX(ax), _fresnel.SchlickFresnel(f0), "smith"),
        "ggx_aniso_conductor_hc": mf(_ggx.GGX(ax, ay), _fresnel.ConductorFresnel(eta, kk), "smith_height_correlated"),
        "ggx_dielectric_vgroove": mf(_ggx.GGX(ax), _fresnel.DielectricFresnel(1.0 + eta), "v_groove"),
        "beckmann_aniso_conductor": mf(_beckmann.Beckmann(ax, ay), _fresnel.ConductorFresnel(eta, kk), "smith"),
        "beckmann_schlick_hc": mf(_beckmann.Beckmann(ax), _fresnel.SchlickFresnel(f0), "smith_height_correlated"),
        "cook_torrance": _cook_torrance.CookTorrance(ax, eta, kk),
        "phong": _phong.Phong(rho, rs, expo),
        "modified_phong": _phong.ModifiedPhong(rho, rs, expo),
        "blinn_phong": _phong.BlinnPhong(rho, rs, expo),
        "ward": _ward.Ward(rho, rs, ax, ay, normalization="ward"),
        "ward_gm": _ward.Ward(rho, rs, ax, ay),
        "oren_nayar": _diffuse.OrenNayar(rho, sigma),
        "oren_nayar_full": _diffuse.OrenNayar(rho, sigma, "full"),
        "burley": _diffuse.BurleyDiffuse(rho, rs),
    }

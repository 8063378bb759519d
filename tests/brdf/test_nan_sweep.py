"""NaN sweep: every public BRDF of ``brdf`` (found from the package's namespace,
so a new model fails here until it is given its parameter edges), in float32 and
float64, gives finite values and finite gradients with respect to wi, wo and
every floating-point leaf of the model, over the edge direction pairs (grazing at
cos = 1e-8, 1e-20 and exactly 0, mirror pairs down to cos = 1e-8, wi = wo,
wi = -wo, below the horizon, normal incidence, random pairs, each also with both
vectors scaled by 1e-3 and by 1e3) crossed with parameters at the edges of each
model's documented range. Values must also be >= 0.

One program per model family and dtype (its variants, e.g. Ward's two
normalisations, evaluated side by side), compiled with ``brdf.check.FAST_COMPILE``.
"""

import inspect

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdf
from brdf import _diffuse, _merl, _microfacet, _ward

DTYPES = (jnp.float32, jnp.float64)
GRAZING = (1e-8, 1e-20, 0.0)  # cos(theta) of the grazing directions
SCALES = (1.0, 1e-3, 1e3)  # lengths of the (otherwise unit) direction vectors
N_PARAM_DRAWS = 8  # each pair meets this many parameter draws
N_RANDOM = 48  # random pairs in the set


# ---------------------------------------------------------------------------
# Direction pairs


def _from_cos(c, phi):
    c, phi = np.broadcast_arrays(np.asarray(c, float), np.asarray(phi, float))
    s = np.sqrt(np.maximum(1.0 - c * c, 0.0))
    return np.stack([s * np.cos(phi), s * np.sin(phi), c], -1)


def _mirror(w):
    return np.concatenate([-w[..., :2], w[..., 2:]], -1)


def edge_pairs(seed: int = 0) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """(wi [N, 3], wo [N, 3], kind of each pair) in float64: unit vectors, then the
    same set scaled by each of SCALES."""
    rng = np.random.default_rng(seed)
    wi, wo, kind = [], [], []

    def add(a, b, k):
        a, b = np.broadcast_arrays(np.atleast_2d(a), np.atleast_2d(b))
        wi.append(a)
        wo.append(b)
        kind.extend([k] * a.shape[0])

    def rand_dirs(n, lo=0.0):
        return _from_cos(rng.uniform(lo, 1.0, n), rng.uniform(0, 2 * np.pi, n))

    levels = (*GRAZING, 1e-6, 1e-4, 1e-2, 0.5, 1.0 - 1e-7, 1.0)
    phis = np.array([0.0, 0.3, np.pi / 2, 2.0, np.pi, 5.0])
    add(rand_dirs(N_RANDOM), rand_dirs(N_RANDOM), "random")
    for c in GRAZING:
        g = _from_cos(np.full(phis.shape, c), phis)
        r = rand_dirs(phis.size)
        add(g, r, f"grazing wi {c:g}")
        add(r, g, f"grazing wo {c:g}")
        for c2 in GRAZING:
            add(g, _from_cos(np.full(phis.shape, c2), 0.3 + phis), f"both grazing {c:g}/{c2:g}")
    for c in levels:
        w = _from_cos(np.full(phis.shape, c), phis)
        add(w, _mirror(w), f"mirror {c:g}")
        add(w, w, f"wi = wo {c:g}")
        add(w, -w, f"wi = -wo {c:g}")
        # near-mirror: the partner's azimuth off by a small angle
        add(w, _mirror(_from_cos(np.full(phis.shape, c), phis + 1e-3)), f"near mirror {c:g}")
    normal = np.array([0.0, 0.0, 1.0])
    r = rand_dirs(8)
    add(normal, r, "normal wi")
    add(r, normal, "normal wo")
    add(normal, normal, "normal both")
    below = _from_cos(-rng.uniform(0.0, 1.0, 8), rng.uniform(0, 2 * np.pi, 8))
    below = np.concatenate([below, _from_cos(np.array([-1e-8, -1.0]), np.array([0.4, 0.0]))])
    up = rand_dirs(below.shape[0])
    add(below, up, "below wi")
    add(up, below, "below wo")
    add(below, below[::-1], "below both")
    wi, wo = np.concatenate(wi), np.concatenate(wo)
    out_i, out_o, out_k = [], [], []
    for s in SCALES:
        out_i.append(wi * s)
        out_o.append(wo * s)
        out_k.extend(k if s == 1.0 else f"{k} x{s:g}" for k in kind)
    return np.concatenate(out_i), np.concatenate(out_o), out_k


# ---------------------------------------------------------------------------
# Parameter edges: per model family, each parameter's values at the edges of its
# documented range (and a random draw inside it, "rand"). Every lane draws each
# parameter independently from its list.

RHO = (0.0, 1.0, "rand")
ALPHA = (0.0, brdf.ALPHA_MIN, 1.0, "logrand")  # 0 is clamped to the floor ALPHA_MIN
EXPONENT = (0.0, 1.0, 1e4, "logrand")


def _draw(rng, spec, n, lo=0.0, hi=1.0):
    """n values drawn from spec: a tuple of numbers and "rand" (uniform in [lo, hi])
    or "logrand" (log-uniform in [max(lo, 1e-4), hi])."""
    idx = rng.integers(0, len(spec), n)
    out = np.empty(n)
    for j, v in enumerate(spec):
        sel = idx == j
        if v == "rand":
            out[sel] = rng.uniform(lo, hi, sel.sum())
        elif v == "logrand":
            a = max(lo, 1e-4)
            out[sel] = np.exp(rng.uniform(np.log(a), np.log(hi), sel.sum()))
        else:
            out[sel] = v
    return out


class _Params:
    """Per-lane parameter columns [n, c] in one dtype."""

    def __init__(self, n, dtype, seed):
        self.n, self.dtype, self.rng = n, dtype, np.random.default_rng(seed)

    def __call__(self, spec, lo=0.0, hi=1.0, c=1):
        cols = [_draw(self.rng, spec, self.n, lo, hi) for _ in range(c)]
        return jnp.asarray(np.stack(cols, -1), self.dtype)


def _microfacets(p):
    dists = {
        "GGX": brdf.GGX,
        "Beckmann": brdf.Beckmann,
    }
    fresnels = {
        # f0 in [0, 1]; conductor eta > 0 (0.01: the fitter's floor, below any metal), k >= 0;
        # dielectric eta > 0, below 1 (total internal reflection) and index matched (1) included
        "SchlickFresnel": lambda: brdf.SchlickFresnel(p((0.0, 1.0, "rand"))),
        "ConductorFresnel": lambda: brdf.ConductorFresnel(p((0.01, 0.2, 1.0, 3.0, "rand"), 0.01, 3.0, 3),
                                                          p((0.0, 5.0, 10.0, "rand"), 0.0, 10.0, 3)),
        "DielectricFresnel": lambda: brdf.DielectricFresnel(p((0.5, 1.0, 1.5, 3.0, "rand"), 1.0, 3.0)),
    }
    # Every masking with every Fresnel term; the distribution alternates so that
    # each meets every masking and every Fresnel term (all pairs of the three
    # factors, in 9 models instead of 18: compile time is what this test pays).
    out = {}
    dist_names = list(dists)
    for i, masking in enumerate(_microfacet.MASKINGS):
        for j, (fn, fres) in enumerate(fresnels.items()):
            dn = dist_names[(i + j) % len(dist_names)]
            aniso = j % 2 == 1  # alpha_y given, or None (isotropic), for each distribution
            d = dists[dn](p(ALPHA, 1e-4, 1.0), p(ALPHA, 1e-4, 1.0) if aniso else None)
            out[f"{dn}/{fn}/{masking}/{'aniso' if aniso else 'iso'}"] = brdf.Microfacet(d, fres(), masking)
    return out


def _merl_table(dtype):
    rng = np.random.default_rng(3)
    t = rng.uniform(0.0, 5.0, (3,) + brdf.MERL_RES)
    t[rng.uniform(size=t.shape) < 0.05] = -1.0  # missing measurements
    return jnp.asarray(t, dtype)


def _nbrdf(dtype):
    # Random weights at the scale of the trained networks: the sweep is about
    # the encoding and the exp - 1 output, not one material.
    rng = np.random.default_rng(4)
    shapes = {"kernel_1": (6, 21), "bias_1": (21,), "kernel_2": (21, 21), "bias_2": (21,), "kernel_3": (21, 3),
              "bias_3": (3,)}
    return brdf.NBRDF(**{k: jnp.asarray(rng.normal(0.0, 0.5, s), dtype) for k, s in shapes.items()})


# family -> function(params, dtype) -> {variant label: model}
FAMILIES = {
    brdf.Lambert: lambda p, dt: {"": brdf.Lambert(p(RHO, c=3))},
    brdf.Microfacet: lambda p, dt: _microfacets(p),
    brdf.Sum: lambda p, dt: {
        "lambert_ggx": brdf.lambert_ggx(p(RHO, c=3), p(RHO), p(ALPHA, 1e-4, 1.0)),
        "oren_nayar+ward": brdf.Sum(brdf.OrenNayar(p(RHO, c=3), p((0.0, np.pi / 2, "rand"), 0, np.pi / 2)),
                                    brdf.Ward(p(RHO), p(RHO), p(ALPHA, 1e-4, 1.0))),
    },
    brdf.Phong: lambda p, dt: {"": brdf.Phong(p(RHO, c=3), p(RHO), p(EXPONENT, 1.0, 1e4))},
    brdf.ModifiedPhong: lambda p, dt: {
        f"normalized={nz}": brdf.ModifiedPhong(p(RHO, c=3), p(RHO), p(EXPONENT, 1.0, 1e4), normalized=nz)
        for nz in (True, False)
    },
    brdf.BlinnPhong: lambda p, dt: {
        f"normalized={nz}": brdf.BlinnPhong(p(RHO, c=3), p(RHO), p(EXPONENT, 1.0, 1e4), normalized=nz)
        for nz in (True, False)
    },
    brdf.Ward: lambda p, dt: {
        nm: brdf.Ward(p(RHO, c=3), p(RHO), p(ALPHA, 1e-4, 1.0), p(ALPHA, 1e-4, 1.0) if i else None, nm)
        for i, nm in enumerate(_ward.NORMALIZATIONS)
    },
    brdf.CookTorrance: lambda p, dt: {
        "": brdf.CookTorrance(p(ALPHA, 1e-4, 1.0), p((0.01, 0.2, 1.0, 3.0, "rand"), 0.01, 3.0, 3),
                              p((0.0, 5.0, 10.0, "rand"), 0.0, 10.0, 3), p((1.0, 1.33, "rand"), 1.0, 2.0),
                              p((0.0, 0.1, "rand"), 0.0, 0.1)),
    },
    brdf.OrenNayar: lambda p, dt: {
        v: brdf.OrenNayar(p(RHO, c=3), p((0.0, np.pi / 2, "rand"), 0.0, np.pi / 2), v) for v in _diffuse.VARIANTS
    },
    brdf.BurleyDiffuse: lambda p, dt: {"": brdf.BurleyDiffuse(p(RHO, c=3), p(RHO))},
    brdf.PoulinFournier: lambda p, dt: {
        "": brdf.PoulinFournier(p(RHO, c=3), p(RHO), p((0.0, 0.5, 1.0, 1e4, "logrand"), 0.5, 1e4),
                                p((0.0, 1e-3, 2.0, 1e3, "rand"), 0.0, 5.0),
                                p((1e-7, brdf._poulin_fournier.H_MIN, 1.0, "logrand"), 1e-6, 1.0)),
    },
    brdf.MERL: lambda p, dt: {i: brdf.MERL(_merl_table(dt), i) for i in _merl.INTERPOLATIONS},
    brdf.NBRDF: lambda p, dt: {"": _nbrdf(dt)},
}


def _public_brdfs():
    return {o for o in vars(brdf).values() if isinstance(o, type) and issubclass(o, brdf.AbstractBRDF)
            and not inspect.isabstract(o)}


def test_every_public_brdf_is_swept():
    """The sweep covers exactly the concrete BRDFs brdf exports, and Microfacet's
    every distribution, Fresnel term and masking."""
    missing = _public_brdfs() - set(FAMILIES)
    assert not missing, f"no NaN-sweep parameter edges for {sorted(c.__name__ for c in missing)}"
    combos = [label.split("/") for label in _microfacets(_Params(1, jnp.float64, 0))]
    parts = []
    for base in (brdf.AbstractMicrofacetDistribution, brdf.AbstractFresnel):
        parts.append({o.__name__ for o in vars(brdf).values() if isinstance(o, type) and issubclass(o, base)
                      and not inspect.isabstract(o)})
    parts += [set(_microfacet.MASKINGS), {"iso", "aniso"}]
    # every pair of factors (distribution, Fresnel, masking, anisotropy) occurs, but Fresnel x anisotropy
    for a in range(4):
        for b in range(a + 1, 4):
            if (a, b) == (1, 3):
                continue
            seen = {(c[a], c[b]) for c in combos}
            want = {(x, y) for x in parts[a] for y in parts[b]}
            assert seen == want, f"Microfacet sweep misses {sorted(want - seen)}"


# ---------------------------------------------------------------------------
# The sweep


def _values_and_grads(models, wi, wo):
    """{label: (f [n, C], (d/dparams, d/dwi, d/dwo))} for models evaluated on the whole batch."""
    out = {}
    for label, model in models.items():
        params, static = eqx.partition(model, eqx.is_inexact_array)

        def total(pr, a, b, static=static):
            f = eqx.combine(pr, static)(a, b)
            return jnp.sum(f), f

        grads, f = jax.grad(total, argnums=(0, 1, 2), has_aux=True)(params, wi, wo)
        out[label] = (f, grads)
    return out


_compiled = jax.jit(_values_and_grads, compiler_options=brdf.check.FAST_COMPILE)


def _bad_lanes(x, n):
    """Boolean [n]: lanes with a non-finite entry (0-d or shared leaves count for all lanes)."""
    a = np.asarray(x)
    if a.ndim == 0 or a.shape[0] != n:
        return np.full(n, not np.all(np.isfinite(a)))
    return ~np.all(np.isfinite(a.reshape(n, -1)), axis=1)


def sweep(family, dtype, seed=0):
    """{(variant, quantity): [kinds of the failing pairs]} for one model family in one dtype."""
    wi, wo, kinds = edge_pairs(seed)
    r = N_PARAM_DRAWS
    n = wi.shape[0] * r
    kinds = kinds * r
    wi = jnp.asarray(np.tile(wi, (r, 1)), dtype)
    wo = jnp.asarray(np.tile(wo, (r, 1)), dtype)
    models = FAMILIES[family](_Params(n, dtype, seed + 1), dtype)
    results = _compiled(models, wi, wo)
    failures = {}
    for label, (f, (gp, gi, go)) in results.items():
        checks = {"value": _bad_lanes(f, n), "value < 0": np.asarray(jnp.any(f < 0, axis=-1)),
                  "d/dwi": _bad_lanes(gi, n), "d/dwo": _bad_lanes(go, n)}
        for path, leaf in jax.tree_util.tree_leaves_with_path(gp):
            checks["d/d" + jax.tree_util.keystr(path)] = _bad_lanes(leaf, n)
        for what, bad in checks.items():
            if bad.any():
                failures[(label, what)] = sorted({kinds[i] for i in np.flatnonzero(bad)})
                failures[(label, what)].insert(0, f"{int(bad.sum())} of {n} lanes")
    return failures


@pytest.mark.parametrize("dtype", DTYPES, ids=lambda d: jnp.dtype(d).name)
@pytest.mark.parametrize("family", list(FAMILIES), ids=lambda c: c.__name__)
def test_nan_sweep(family, dtype):
    failures = sweep(family, dtype)
    assert not failures, "\n".join(f"{family.__name__} {v} {w}: {', '.join(k[:12])}" for (v, w), k in failures.items())

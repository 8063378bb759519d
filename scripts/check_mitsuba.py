"""Cross-check brdf against Mitsuba 3, an independent renderer users trust.

Compares f_r of our models (evaluated in float64) with Mitsuba 3 (``scalar_rgb``:
float32, no system library needed) on random direction pairs:

- GGX conductor, isotropic and anisotropic: ``Microfacet(GGX, ConductorFresnel)``
  vs ``roughconductor`` (distribution ggx): exact agreement expected (1e-4 relative).
- Beckmann conductor vs ``roughconductor`` (distribution beckmann): Mitsuba uses
  Walter's rational approximation of Smith's G1 (up to 0.35% per G1), we the
  exact erf form, so the tolerance there is 0.7% (two G1 factors). A second
  Beckmann case rebuilds f_r from our D and Fresnel with Walter's rational G1,
  which must then agree to 1e-4: the difference is the approximation alone.
- Lambert vs ``diffuse``: 1e-4 relative.
- BurleyDiffuse vs ``principled`` with specular = 0, metallic = 0 (its diffuse lobe
  is Burley 2012 with retro-reflection; no specular lobe remains): 1e-4 relative.

Mitsuba 3 has no Oren-Nayar (``roughdiffuse`` was dropped after Mitsuba 0.6), so
that model has no renderer to check against here.

Mitsuba's ``eval`` includes the cosine foreshortening factor: we divide by cos(theta_o).

Usage:
    pip install -e ".[test]"     # Mitsuba comes with the test extras
    python scripts/check_mitsuba.py [--pairs 2000] [--seed 0]

Exits with status 1 if any model disagrees beyond its tolerance.
"""

from __future__ import annotations

import sys

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _common import parser  # noqa: E402

import brdf  # noqa: E402

ETA = [0.2, 0.9, 1.1]  # roughly gold at R, G, B
K = [3.9, 2.4, 2.2]
RGB = [0.2, 0.5, 0.8]


def _pairs(n: int, seed: int, min_cos: float = 0.02):
    """Random pairs over the upper hemisphere, cos(theta) >= min_cos (float32
    rounding in Mitsuba dominates any comparison closer to the horizon)."""
    rng = np.random.default_rng(seed)

    def dirs():
        z = min_cos + (1 - min_cos) * rng.random(n)
        phi = 2 * np.pi * rng.random(n)
        r = np.sqrt(1 - z * z)
        d = np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)
        # round to float32 first, so that both sides see the same directions
        d = d.astype(np.float32).astype(np.float64)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    return dirs(), dirs()


def _mitsuba_eval(bsdf, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    import mitsuba as mi

    ctx = mi.BSDFContext()
    out = np.empty((wi.shape[0], 3))
    si = mi.SurfaceInteraction3f()
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    for i in range(wi.shape[0]):
        si.wi = mi.Vector3f(*wi[i])
        v = bsdf.eval(ctx, si, mi.Vector3f(*wo[i]))
        out[i] = (v[0], v[1], v[2])
    return out / wo[:, 2:3]  # Mitsuba returns f_r cos(theta_o)


def _walter_g1(w, alpha_x, alpha_y):
    """Walter et al. 2007's rational approximation of Beckmann's Smith G1 (eq. 27)."""
    z = w[..., 2:3]
    s = jnp.sqrt((alpha_x * w[..., 0:1]) ** 2 + (alpha_y * w[..., 1:2]) ** 2)
    a = z / jnp.maximum(s, 1e-300)
    g = (3.535 * a + 2.181 * a * a) / (1 + 2.276 * a + 2.577 * a * a)
    return jnp.where(a < 1.6, g, 1.0)


class _BeckmannRationalG1(brdf.AbstractBRDF):
    """Our Beckmann D and conductor Fresnel with Walter's rational G1: Mitsuba's recipe."""

    alpha_x: float
    alpha_y: float

    def __call__(self, wi, wo):
        wm = brdf.safe_normalize(wi + wo)
        d = brdf.Beckmann(self.alpha_x, self.alpha_y).D(wm)
        f = brdf.fresnel_conductor(brdf.dot(wi, wm), jnp.asarray(ETA), jnp.asarray(K))
        g = _walter_g1(wi, self.alpha_x, self.alpha_y) * _walter_g1(wo, self.alpha_x, self.alpha_y)
        return d * f * g / (4 * wi[..., 2:3] * wo[..., 2:3])

    def fittable(self):
        return {}


def cases():
    """(name, our model, Mitsuba dict, relative tolerance)."""
    rgb = lambda v: {"type": "rgb", "value": v}  # noqa: E731
    eta, k = jnp.asarray(ETA), jnp.asarray(K)
    out = []
    for ax, ay in ((0.1, 0.1), (0.3, 0.3), (0.7, 0.7), (0.3, 0.1)):
        out.append(
            (
                f"ggx conductor ax={ax} ay={ay}",
                brdf.Microfacet(brdf.GGX(ax, ay), brdf.ConductorFresnel(eta, k), "smith"),
                {"type": "roughconductor", "distribution": "ggx", "alpha_u": ax, "alpha_v": ay,
                 "eta": rgb(ETA), "k": rgb(K)},
                1e-4,
            )
        )
    for ax, ay in ((0.2, 0.2), (0.5, 0.2)):
        out.append(
            (
                f"beckmann conductor ax={ax} ay={ay}",
                brdf.Microfacet(brdf.Beckmann(ax, ay), brdf.ConductorFresnel(eta, k), "smith"),
                {"type": "roughconductor", "distribution": "beckmann", "alpha_u": ax, "alpha_v": ay,
                 "eta": rgb(ETA), "k": rgb(K)},
                7e-3,  # Mitsuba's rational G1 approximation: <= 0.35% per G1
            )
        )
        out.append(
            (
                f"beckmann, Walter G1 ax={ax} ay={ay}",
                _BeckmannRationalG1(ax, ay),
                {"type": "roughconductor", "distribution": "beckmann", "alpha_u": ax, "alpha_v": ay,
                 "eta": rgb(ETA), "k": rgb(K)},
                1e-4,
            )
        )
    out.append(("lambert", brdf.Lambert(jnp.asarray(RGB)), {"type": "diffuse", "reflectance": rgb(RGB)}, 1e-4))
    for r in (0.0, 0.5, 1.0):
        out.append(
            (
                f"burley diffuse roughness={r}",
                brdf.BurleyDiffuse(jnp.asarray(RGB), r),
                {"type": "principled", "base_color": rgb(RGB), "roughness": r, "metallic": 0.0,
                 "specular": 0.0, "spec_tint": 0.0},
                1e-4,
            )
        )
    return out


def cross_check(n_pairs: int = 2000, seed: int = 0, variant: str = "scalar_rgb", only=None) -> list[dict]:
    """Run every case (or those whose name starts with one of ``only``); returns
    one dict per case with the relative errors."""
    import mitsuba as mi

    mi.set_variant(variant)
    wi, wo = _pairs(n_pairs, seed)
    results = []
    for name, ours, spec, tol in cases():
        if only is not None and not any(name.startswith(o) for o in only):
            continue
        mine = np.asarray(jax.jit(jax.vmap(ours))(jnp.asarray(wi), jnp.asarray(wo)))
        mine = np.broadcast_to(mine, (n_pairs, 3))
        theirs = _mitsuba_eval(mi.load_dict(spec), wi, wo)
        # relative error against the larger magnitude; tiny values (< 1e-6 of the
        # peak, below float32 resolution of Mitsuba's arithmetic) compare absolutely
        scale = np.maximum(np.maximum(np.abs(mine), np.abs(theirs)), 1e-6 * np.abs(theirs).max())
        rel = np.abs(mine - theirs) / scale
        results.append(
            dict(name=name, tol=tol, max_rel=float(rel.max()), p999_rel=float(np.quantile(rel, 0.999)),
                 ok=bool(rel.max() <= tol), n=n_pairs)
        )
    return results


def main(argv=None) -> int:
    ap = parser(__doc__)
    ap.add_argument("--pairs", type=int, default=2000, help="direction pairs per model (default 2000)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--variant", default="scalar_rgb", help="Mitsuba variant (default scalar_rgb)")
    args = ap.parse_args(argv)
    try:
        import mitsuba  # noqa: F401
    except ImportError:
        print("mitsuba is not installed: pip install -e \".[test]\" (or pip install mitsuba)", file=sys.stderr)
        return 2
    results = cross_check(args.pairs, args.seed, args.variant)
    print(f"{'model':38s} {'pairs':>6s} {'max rel err':>12s} {'99.9% rel':>10s} {'tol':>8s}  result")
    for r in results:
        print(f"{r['name']:38s} {r['n']:6d} {r['max_rel']:12.3e} {r['p999_rel']:10.3e} {r['tol']:8.0e}  "
              f"{'ok' if r['ok'] else 'FAIL'}")
    return 0 if all(r["ok"] for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())

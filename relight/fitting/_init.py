"""Starting points that do not need luck (per sample, vmapped):

1. photometric stereo (Woodham 1980) for the normal and the albedo, on the
   lights least affected by specular reflection and shadow: the lights whose
   half vector is far from the (surface) normal, minus the darkest fifth
   (attached and cast shadows) and the brightest tenth of the rest
   (highlights and interreflections);
2. for a rung with a specular lobe, a 1-D search over roughness in which
   (rho_d, rho_s) are solved in closed form, because the model is linear in
   them at a fixed roughness (Schlick: F = F0 (1 - c^5) + c^5; Blinn-Phong's
   lobe is linear in its albedo).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from brdf import safe_div, safe_normalize

from ._model import BLINN_PHONG, GGX_ANISO, Layout, Params, frame, specular
from ._spd import spd_solve

# Lights with a half vector within this angle of the normal are left out of
# photometric stereo (a GGX lobe of alpha 0.3 is down to ~5% of its peak there).
_SPEC_EXCLUDE_DEG = 30.0
_DARK_FRACTION, _BRIGHT_FRACTION = 0.2, 0.1
# Minimum lights for photometric stereo on the selected subset (else all valid).
_MIN_PS_LIGHTS = 6


def _quantile_masked(x, valid, q):
    """The q-quantile (lower) of x over ``valid`` entries (x [N])."""
    s = jnp.sort(jnp.where(valid, x, jnp.inf))
    k = jnp.sum(valid.astype(x.dtype))
    idx = jnp.clip(jnp.floor(q * (k - 1)).astype(jnp.int32), 0, x.shape[0] - 1)
    return s[idx]


def photometric_stereo(obs, w, wi, wo, irr, fit_normal: bool):
    """(normal [3] in the surface frame, rho_d [3]) from Lambertian least squares
    on the selected lights. obs, w, irr [N, C]; wi, wo [N, 3]. Unit-free: it
    uses obs / irr and ratios of sums of obs x irr and irr^2."""
    valid = w[:, 0] > 0
    shade = jnp.mean(safe_div(obs, jnp.where(irr > 0, irr, 1.0)), axis=1)  # grey radiance per unit irradiance
    h = safe_normalize(wi + wo)
    away = h[:, 2] < jnp.cos(jnp.deg2rad(_SPEC_EXCLUDE_DEG))
    lo = _quantile_masked(shade, valid, _DARK_FRACTION)
    hi = _quantile_masked(shade, valid, 1.0 - _BRIGHT_FRACTION)
    sel = valid & away & (shade >= lo) & (shade <= hi)
    sel = jnp.where(jnp.sum(sel) >= _MIN_PS_LIGHTS, sel, valid & (shade >= lo))
    sel = jnp.where(jnp.sum(sel) >= 3, sel, valid)
    s = sel.astype(obs.dtype)
    z = jnp.asarray([0.0, 0.0, 1.0], obs.dtype)
    if fit_normal:
        A = jnp.einsum("n,ni,nj->ij", s, wi, wi) + 1e-6 * jnp.eye(3, dtype=obs.dtype)
        b = spd_solve(A, jnp.einsum("n,n,ni->i", s, shade, wi))
        n = safe_normalize(b)
        # A normal facing away from the camera-side hemisphere is a failed
        # solve (too few or coplanar lights): keep the surface's.
        # So is a normal with the camera behind it: the samples were seen.
        wo_mean = safe_normalize(jnp.sum(s[:, None] * wo, 0) + 1e-12 * z)
        ok = jnp.all(jnp.isfinite(n)) & (n[2] > 0.05) & (n @ wo_mean > 0.05)
        n = jnp.where(ok, n, z)
    else:
        n = z
    cos_i = jnp.maximum(wi @ n, 0.0)[:, None]
    basis = cos_i * irr / jnp.pi
    rho = safe_div(jnp.sum(s[:, None] * basis * obs, 0), jnp.sum(s[:, None] * basis * basis, 0))
    return n, jnp.clip(rho, 1e-3, 0.999)


def _alpha_grid(floor, dtype):
    base = jnp.asarray([0.03, 0.05, 0.08, 0.12, 0.18, 0.25, 0.35, 0.5, 0.7, 1.0], dtype)
    return jnp.maximum(base, floor * 1.02)


def specular_start(obs, w, wi, wo, irr, normal, lay: Layout, mix=None):
    """Closed-form (rho_d, rho_s) on a roughness grid; keep the best. Returns Params.

    ``mix`` (optional): a linear map of per-observation bases [N, C] to the
    space of ``obs`` and ``w`` [M, C] (relight.fitting.fit_patterns: the
    pattern weights W x visibility), applied to the model's terms before the
    closed-form solve; the model stays linear in (rho_d, rho_s) after it."""
    R = frame(normal, jnp.zeros((), obs.dtype))
    wi_f, wo_f = wi @ R.T, wo @ R.T
    cos_i = jnp.maximum(wi_f[:, 2:3], 0.0)
    lit = (wi_f[:, 2:3] > 0) & (wo_f[:, 2:3] > 0)
    d = jnp.where(lit, cos_i * irr / jnp.pi, 0.0)  # multiplies rho_d per channel
    mix = (lambda x: x) if mix is None else mix
    d = mix(d)
    one, zero = jnp.ones(1, obs.dtype), jnp.zeros(1, obs.dtype)

    def at(alpha):
        al = jnp.stack([alpha, alpha])
        if lay.model == BLINN_PHONG:
            a = specular(lay.model, one, al, wi_f, wo_f) * cos_i * irr
            b = jnp.zeros_like(a)
        else:
            s1 = specular(lay.model, one, al, wi_f, wo_f)
            s0 = specular(lay.model, zero, al, wi_f, wo_f)
            a, b = (s1 - s0) * cos_i * irr, s0 * cos_i * irr
        a, b = mix(a), mix(b)
        y = obs - b
        dd, da, aa = jnp.sum(w * d * d, 0), jnp.sum(w * d * a, 0), jnp.sum(w * a * a)
        dy, ay = jnp.sum(w * d * y, 0), jnp.sum(w * a * y)
        # A guard for a channel without lit observations, not a scale: the
        # driver normalises irr to RMS 1 per sample, so dd ~ n_lit / 20.
        dd_s = jnp.maximum(dd, 1e-12)
        # Schur complement eliminating the three diagonal rho_d unknowns.
        schur = aa - jnp.sum(da * da / dd_s)
        rs = jnp.clip(safe_div(ay - jnp.sum(da * dy / dd_s), schur), 1e-3, 0.999)
        rho = jnp.clip((dy - da * rs) / dd_s, 1e-3, 0.999)
        r = obs - (d * rho[None] + a * rs + b)
        return jnp.sum(w * r * r), rho, rs

    grid = _alpha_grid(lay.alpha_floor, obs.dtype)
    costs, rhos, rss = jax.vmap(at)(grid)
    k = jnp.argmin(costs)
    alpha = jnp.stack([grid[k], grid[k]])
    return Params(rho_d=rhos[k], rho_s=rss[k][None], alpha=alpha, phi=jnp.zeros((), obs.dtype), normal=normal)


def start(obs, w, wi, wo, irr, lay: Layout) -> Params:
    """The full start for a rung (normal, albedo, then the lobe if any)."""
    n, rho = photometric_stereo(obs, w, wi, wo, irr, lay.normals)
    if lay.model < BLINN_PHONG:
        return Params(rho_d=rho, rho_s=jnp.zeros(1, obs.dtype), alpha=jnp.full(2, 0.5, obs.dtype),
                      phi=jnp.zeros((), obs.dtype), normal=n)
    p = specular_start(obs, w, wi, wo, irr, n, lay)
    if lay.model >= GGX_ANISO:
        # Start isotropic; phi = 0 is the surface tangent (or its projection).
        p["alpha"] = jnp.stack([p["alpha"][0], p["alpha"][0] * 0.999 + 1e-4])
    return p

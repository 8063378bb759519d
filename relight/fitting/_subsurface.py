"""Fitting subsurface scattering (the top rung of the model ladder).

Model (what ``stage.simulate`` renders with a ``stage.Subsurface``; Jensen et
al. 2001 eq. 5 through the diffusion operator):

    L(v, l, p) = specular(v, l, p)
                 + T_out(p, v) / pi * A_p * sum_q w_pq(d_p) T_in(q, l) cos_i(q, l) E_l(q)

with Christensen & Burley 2015's profile: albedo A_p and shape length
d_p = mfp / s(A_p) (their eq. 8 "dmfp" fit), mfp the diffuse mean free path
per colour channel. At a fixed d the model is linear in A_p, so per sample the
albedo is solved in closed form; the mean free path couples neighbours, so it
is fitted per region (a label map; default one region) by a 1-D search per
channel: a log-spaced grid, then golden-section refinement, alternating with
the albedo update (d depends on A). The specular lobe and normals come from a
prior :func:`relight.fit` and are held fixed.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

import brdf
import skin_bssrdf
import stage

from ..materials._maps import SUBSURFACE, LadderBRDF
from ._driver import Fit
from ._model import view_above_horizon

_GOLDEN = 0.5 * (np.sqrt(5.0) - 1.0)


def _terms(capture, surface, fitted: Fit, eta):
    """y = observed minus fitted specular [V, L, P, C], validity [V, L, P],
    transmitted irradiance E [L, P, C] (``stage.subsurface_irradiance``), the
    local views wo [V, P, 3] (for ``stage.subsurface_exitance``), and the local
    Lambert prediction of the fit [V, L, P, C] (for the model choice)."""
    maps = fitted.maps(surface)
    fr = maps.frame(surface)
    # Each sample's fitted lobe alone (no diffuse term): Lambert samples have none.
    spec_brdf = LadderBRDF(jnp.zeros_like(maps.rho_d), maps.rho_s, maps.alpha, maps.model[:, None])
    y, wo_v, lam = [], [], []
    E = None
    valid = np.asarray(capture.mask)
    lit = np.any(valid, axis=0)  # [L, P]: a light's visibility does not depend on the view
    for v, cam in enumerate(capture.cameras):
        wi, wo, irr = stage.shading_directions(fr, capture.rig, cam)
        spec = stage.reflected_radiance_lights(spec_brdf, wi, wo, irr)
        y.append(np.asarray(capture.radiance[v], np.float64) - np.asarray(spec, np.float64))
        # The fit's local Lambert term, with the view kept above the fitted horizon as the fitter keeps it.
        lambert = stage.reflected_radiance_lights(brdf.Lambert(maps.rho_d), wi, view_above_horizon(wo), irr)
        lam.append(np.asarray(lambert, np.float64))
        wo_v.append(np.asarray(wo, np.float64))
        if E is None:
            E = np.asarray(stage.subsurface_irradiance(wi, irr, eta, jnp.asarray(lit)), np.float64)
    return np.stack(y), valid, E, np.stack(wo_v), np.stack(lam)


def fit_subsurface(capture: stage.Capture, surface: stage.Surface, fitted: Fit, *, regions=None,
                   mfp_range=(0.05, 8.0), grid: int = 8, refine: int = 8, iterations: int = 2,
                   search_lights: int = 48, eta: float = 1.4,
                   radius_mm: float | None = None, max_neighbours: int | None = None, progress=None) -> Fit:
    """Fit the diffuse mean free path (mm, per channel, per region) and the
    per-sample albedo of the subsurface rung, given a BRDF ``fitted`` by
    :func:`relight.fit` (its specular lobe and normals are kept).

    ``regions``: int labels [P] (default: one region). ``mfp_range``: the search
    bracket (mm). Each region switches to the subsurface rung only if that
    lowers its squared residual by more than two standard errors of the noise
    (s^2 sqrt(2 n) for n observations); otherwise it keeps the fit's local
    Lambert term (mfp reported 0). ``radius_mm``: the operator's neighbour
    radius (default: 99% of the energy of the widest profile searched).
    ``progress(phase, done, total)`` (``stage.Progress``): phase "fit
    subsurface", one unit per evaluation of the mean-free-path search.
    Returns a new ``Fit`` with ``mfp`` [P, 3], ``rho_d`` = the profile albedo and
    ``model`` = SUBSURFACE where chosen.
    """
    V, L, P, C = capture.radiance.shape
    if surface.num_samples != P or fitted.rho_d.shape[0] != P:
        raise ValueError(f"fit_subsurface: capture ({P}), surface ({surface.num_samples}) and fit "
                         f"({fitted.rho_d.shape[0]}) must have the same samples")
    lo, hi = (float(x) for x in mfp_range)
    if not 0 < lo < hi:
        raise ValueError(f"fit_subsurface: mfp_range must be 0 < lo < hi, got {mfp_range}")
    labels = np.zeros(P, np.int64) if regions is None else np.asarray(regions)
    if labels.shape != (P,) or not np.issubdtype(labels.dtype, np.integer) or labels.min() < 0:
        raise ValueError(f"fit_subsurface: regions must be non-negative int labels of shape [{P}]")
    R = int(labels.max()) + 1
    bar = stage.Phase(progress, "fit subsurface", iterations * (grid + refine))
    y, valid, E, wo, lam = _terms(capture, surface, fitted, eta)
    wo = jnp.asarray(wo)[:, None]  # [V, 1, P, 3] against the lights of S
    vm = valid[..., None].astype(np.float64)  # [V, L, P, 1]
    if radius_mm is None:
        widest = skin_bssrdf.Burley(jnp.full((C,), 0.5), jnp.full((C,), hi / 3.5))
        radius_mm = float(np.max(np.asarray(skin_bssrdf.energy_radius(widest, 0.99))))
    op = skin_bssrdf.DiffusionOperator.build(np.asarray(surface.position), np.asarray(surface.area), radius_mm,
                                             max_neighbours=max_neighbours)
    # The search runs on a subset of lights: each evaluation applies the
    # operator once per light, and a few dozen lights pin one length per channel.
    sub = np.unique(np.linspace(0, L - 1, min(search_lights, L)).round().astype(int))
    y_all, vm_all, E_all = y, vm, E
    y, vm, E = y[:, sub], vm[:, sub], E[sub]
    Ej = jnp.asarray(E)
    scale = skin_bssrdf.SCALE_FITS["dmfp"]

    @jax.jit
    def basis(d, E):
        """k [V, L, P, C]: the radiance per unit albedo for shape lengths d [P, C]."""
        prof = skin_bssrdf.Burley(jnp.ones_like(d), d)
        S = jax.vmap(lambda e: op.apply(prof, e))(E)  # [L, P, C]
        return stage.subsurface_exitance(S[None], wo, eta)

    def solve(mfp_rc, A):
        """Albedo [P, C] and per (region, channel) SSE for mfp [R, C] at albedo A (for d)."""
        d = jnp.asarray(mfp_rc[labels] / np.asarray(scale(jnp.asarray(A))))
        k = np.asarray(basis(jnp.maximum(d, 1e-4), Ej))
        num = np.sum(vm * y * k, axis=(0, 1))
        den = np.sum(vm * k * k, axis=(0, 1))
        # den = 0 only where a sample has no valid observation (no absolute floor:
        # den is in the capture's units squared, ~1e-26 for an intensity-1 rig x 1e-6).
        A_new = np.clip(np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0), 0.0, 1.0)
        r = vm * (y - A_new[None, None] * k)
        sse_p = np.sum(r * r, axis=(0, 1))  # [P, C]
        sse = np.stack([np.bincount(labels, sse_p[:, c], minlength=R) for c in range(C)], 1)
        return A_new, sse

    A = np.clip(np.asarray(fitted.rho_d, np.float64), 0.01, 1.0)
    g = np.geomspace(lo, hi, grid)
    mfp = np.full((R, C), np.sqrt(lo * hi))
    for _ in range(iterations):
        # Grid: the bracket around the best grid value of each region and channel.
        sse_g = []
        for x in g:
            sse_g.append(solve(np.full((R, C), x), A)[1])
            bar.advance()
        k = np.argmin(np.stack(sse_g), axis=0)  # [R, C]
        a = np.log(g[np.maximum(k - 1, 0)])
        b = np.log(g[np.minimum(k + 1, grid - 1)])
        # Golden section in log mfp, every (region, channel) at once.
        x1 = b - _GOLDEN * (b - a)
        x2 = a + _GOLDEN * (b - a)
        f1 = solve(np.exp(x1), A)[1]
        f2 = solve(np.exp(x2), A)[1]
        for _ in range(refine):
            left = f1 < f2
            b = np.where(left, x2, b)
            a = np.where(left, a, x1)
            x2n = np.where(left, x1, a + _GOLDEN * (b - a))
            x1n = np.where(left, b - _GOLDEN * (b - a), x2)
            fx = solve(np.exp(np.where(left, x1n, x2n)), A)[1]
            f1, f2 = np.where(left, fx, f2), np.where(left, f1, fx)
            x1, x2 = x1n, x2n
            bar.advance()
        mfp = np.exp(0.5 * (a + b))
        A, sse = solve(mfp, A)
    # Final albedo and residuals on every light.
    y, vm, E = y_all, vm_all, E_all
    Ej = jnp.asarray(E)
    A, sse = solve(mfp, A)

    # Model choice per region: subsurface only where it explains the data better than noise can.
    r_local = vm * (y - lam)
    sse_local_p = np.sum(r_local * r_local, axis=(0, 1))
    sse_local = np.stack([np.bincount(labels, sse_local_p[:, c], minlength=R) for c in range(C)], 1).sum(1)
    n = np.bincount(labels, np.sum(valid, axis=(0, 1)) * C, minlength=R).astype(np.float64)
    s2 = sse.sum(1) / np.maximum(n, 1.0)
    chosen_r = (sse_local - sse.sum(1)) > 2.0 * s2 * np.sqrt(2.0 * np.maximum(n, 1.0))
    chosen = chosen_r[labels]
    rho_d = np.where(chosen[:, None], A, np.asarray(fitted.rho_d))
    mfp_p = np.where(chosen[:, None], mfp[labels], 0.0)
    model = np.where(chosen, SUBSURFACE, np.asarray(fitted.model))
    dt = fitted.rho_d.dtype
    return Fit(rho_d=jnp.asarray(rho_d, dt), rho_s=fitted.rho_s, alpha=fitted.alpha, normal=fitted.normal,
               tangent=fitted.tangent, model=jnp.asarray(model, jnp.int32), residual=fitted.residual,
               heldout=fitted.heldout, result=fitted.result, steps=fitted.steps, observed=fitted.observed,
               uncertainty=fitted.uncertainty, alpha_floor=fitted.alpha_floor, mfp=jnp.asarray(mfp_p, dt),
               solver=fitted.solver)

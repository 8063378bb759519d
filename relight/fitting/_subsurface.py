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

``per="texel"`` then fits every texel's (mfp, albedo) per channel jointly
(the problem is separable per texel: :mod:`._subsurface_texel`) with a weak
prior toward the region value; ``per="auto"`` chooses per texel between the
fit's local Lambert term, the region's and the texel's own mean free path on
held-out lights (docs/fit.md, "Per-texel subsurface").
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import brdf
import skin_bssrdf
import stage

from ..materials._maps import SUBSURFACE, LadderBRDF
from . import _subsurface_texel as _tx
from ._model import view_above_horizon
from ._result import Fit

_GOLDEN = 0.5 * (np.sqrt(5.0) - 1.0)


def _terms(capture, surface, fitted: Fit, eta):
    """y = observed minus fitted specular [V, L, P, C], validity [V, L, P],
    transmitted irradiance E [L, P, C] (``stage.subsurface_irradiance``), the
    local views wo [V, P, 3] (for ``stage.subsurface_exitance``), and the local
    Lambert prediction per unit albedo [V, L, P, C] (for the model choice).

    The validity returned is the capture's mask (lit and seen). (Widening it to
    every light of a seeing view, for the glow that diffuses into a sample's
    shadow, was tried: +1.6 dB relit on the demo's head, but mean free paths
    2-3x too large with a 1-sigma of 0.2 on the test sphere's 0.5 mm area.)"""
    maps = fitted.maps(surface)
    fr = maps.frame(surface)
    # Each sample's fitted lobe alone (no diffuse term): Lambert samples have none.
    spec_brdf = LadderBRDF(jnp.zeros_like(maps.rho_d), maps.rho_s, maps.alpha, maps.model[:, None])
    y, wo_v, lam = [], [], []
    E = None
    mask = np.asarray(capture.mask)
    lit = jnp.asarray(np.any(mask, axis=0))  # [L, P]: a light's visibility does not depend on the view
    for v, cam in enumerate(capture.cameras):
        spec, lambert, wo, e = _view_terms(fr, capture.rig, cam, spec_brdf, jnp.asarray(eta, fr.normal.dtype), lit)
        y.append(np.asarray(capture.radiance[v], np.float64) - np.asarray(spec, np.float64))
        lam.append(np.asarray(lambert, np.float64))
        wo_v.append(np.asarray(wo, np.float64))
        if E is None:
            E = np.asarray(e, np.float64)
    return np.stack(y), mask, E, np.stack(wo_v), np.stack(lam)


@eqx.filter_jit
def _view_terms(fr, rig, cam, spec_brdf, eta, lit):
    """One view's terms of :func:`_terms` as one program (eager, each of their dozens of operations would
    compile on its own for every new capture size): the lobe's radiance [L, P, C], the local Lambert
    prediction per unit albedo [L, P, C], the local views wo [P, 3] and the transmitted irradiance E [L, P, C]."""
    wi, wo, irr = stage.shading_directions(fr, rig, cam)
    spec = stage.reflected_radiance_lights(spec_brdf, wi, wo, irr)
    # The fit's local Lambert term, with the view kept above the fitted horizon as the fitter keeps it.
    lambert = stage.reflected_radiance_lights(brdf.Lambert(jnp.ones_like(spec_brdf.rho_d)), wi,
                                              view_above_horizon(wo), irr)
    return spec, lambert, wo, stage.subsurface_irradiance(wi, irr, eta, lit)


def _reduced(y, valid, E, wo, eta, dt):
    """The texel fit's data reduced over views (``_subsurface_texel.reduce_views``) and each texel's
    irradiance unit (``_subsurface_texel.irradiance_unit``), from :func:`_terms`' y, validity, E and wo."""
    # The outgoing factor F_t(cos_o) / pi per view and sample: the views reduce exactly (_subsurface_texel).
    f_out = np.asarray(stage.subsurface_exitance(jnp.ones(wo.shape[:2] + (1,), dt), jnp.asarray(wo, dt), eta),
                       np.float64)[..., 0]
    data = _tx.reduce_views(y, valid, f_out)
    return data, _tx.irradiance_unit(E, data)


@jax.jit(static_argnames=("eta",))
def _basis(op, d, E, wo, *, eta):
    """k [V, L, P, C]: the radiance per unit albedo for shape lengths d [P, C] through the operator ``op``, the
    transmitted irradiance E [L, P, C] and the local views wo [V, 1, P, 3]. At module level with the operator and
    views as arguments, not a closure over them: one compilation per shape for every region search of a process
    (and a persistent-cache entry across processes), where a closure was traced and compiled again on every call
    of ``fit_subsurface``."""
    prof = skin_bssrdf.Burley(jnp.ones_like(d), d)
    S = jax.vmap(lambda e: op.apply(prof, e))(E)  # [L, P, C]
    return stage.subsurface_exitance(S[None], wo, eta)


def _region_search(y, vm, E, wo, op, labels, R, lo, hi, grid, refine, iterations, search, final, A0, bar, eta):
    """The per-region mean free path: a log grid then golden-section refinement
    per (region, channel) on the ``search`` lights, alternating with the
    closed-form albedo; then the albedo on the ``final`` lights. Returns
    (mfp [R, C], A [P, C], per-sample SSE [P, C] on ``final``)."""
    C = y.shape[-1]
    scale = skin_bssrdf.SCALE_FITS["dmfp"]

    def solve(mfp_rc, A, lights):
        """Albedo [P, C] and per (region, channel) SSE for mfp [R, C] at albedo A (for d)."""
        yy, vv = y[:, lights], vm[:, lights]
        d = jnp.asarray(mfp_rc[labels] / np.asarray(scale(jnp.asarray(A))))
        k = np.asarray(_basis(op, jnp.maximum(d, 1e-4), jnp.asarray(E[lights]), wo, eta=eta))
        num = np.sum(vv * yy * k, axis=(0, 1))
        den = np.sum(vv * k * k, axis=(0, 1))
        # den = 0 only where a sample has no valid observation (no absolute floor:
        # den is in the capture's units squared, ~1e-26 for an intensity-1 rig x 1e-6).
        A_new = np.clip(np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0), 0.0, 1.0)
        r = vv * (yy - A_new[None, None] * k)
        sse_p = np.sum(r * r, axis=(0, 1))  # [P, C]
        sse = np.stack([np.bincount(labels, sse_p[:, c], minlength=R) for c in range(C)], 1)
        return A_new, sse, sse_p

    A = A0
    g = np.geomspace(lo, hi, grid)
    mfp = np.full((R, C), np.sqrt(lo * hi))
    for _ in range(iterations):
        # Grid: the bracket around the best grid value of each region and channel.
        sse_g = []
        for x in g:
            sse_g.append(solve(np.full((R, C), x), A, search)[1])
            bar.advance()
        k = np.argmin(np.stack(sse_g), axis=0)  # [R, C]
        a = np.log(g[np.maximum(k - 1, 0)])
        b = np.log(g[np.minimum(k + 1, grid - 1)])
        # Golden section in log mfp, every (region, channel) at once.
        x1 = b - _GOLDEN * (b - a)
        x2 = a + _GOLDEN * (b - a)
        f1 = solve(np.exp(x1), A, search)[1]
        f2 = solve(np.exp(x2), A, search)[1]
        for _ in range(refine):
            left = f1 < f2
            b = np.where(left, x2, b)
            a = np.where(left, a, x1)
            x2n = np.where(left, x1, a + _GOLDEN * (b - a))
            x1n = np.where(left, b - _GOLDEN * (b - a), x2)
            fx = solve(np.exp(np.where(left, x1n, x2n)), A, search)[1]
            f1, f2 = np.where(left, fx, f2), np.where(left, f1, fx)
            x1, x2 = x1n, x2n
            bar.advance()
        mfp = np.exp(0.5 * (a + b))
        A = solve(mfp, A, search)[0]
    A, _, sse_p = solve(mfp, A, final)
    return mfp, A, sse_p


def _region_sigma(info, labels, R):
    """1-sigma of each region's shared ln mfp [R, C]: the texels' Fisher
    informations (albedo marginalised) add; inf where they sum to 0."""
    tot = np.stack([np.bincount(labels, info[:, c], minlength=R) for c in range(info.shape[1])], 1)
    return np.where(tot > 0, 1.0 / np.sqrt(np.where(tot > 0, tot, 1.0)), np.inf)


def _lambert_albedo(y, vm, lam, lights):
    """The local Lambert albedo [P, C] in closed form (least squares on the
    ``lights`` weights [L], clipped to [0, 1]): ``lam`` is the prediction per
    unit albedo, next to the fitted lobe that ``y`` already excludes."""
    t = lights[None, :, None, None]
    num = np.sum(t * vm * y * lam, axis=(0, 1))
    den = np.sum(t * vm * lam * lam, axis=(0, 1))
    return np.clip(np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0), 0.0, 1.0)


def _lambert_scores(y, vm, lam, train, held):
    """The local Lambert rung with its albedo solved on the training lights:
    SSE [P, C] on the training lights and the held-out squared error per
    light [P, C, L]."""
    g = _lambert_albedo(y, vm, lam, train)
    r2 = vm * (y - g[None, None] * lam) ** 2
    err_h = np.transpose(np.sum(held[None, :, None, None] * r2, axis=0), (1, 2, 0))
    return np.sum(train[None, :, None, None] * r2, axis=(0, 1)), err_h


def _ladder_choice(err_h, sse_f, seen, n_f):
    """The simplest rung per texel whose held-out error is within noise of the
    best's, relight.fit's rule: err_h [K, P, C, L] held-out squared errors per
    light (views summed) of the rungs, simplest first; sse_f [K, P, C] their
    training SSEs (both zero off their lights); seen [P, L] valid views per
    held-out light (n_h = their sum x C); n_f [P] training observations x C. With s^2 the richest
    rung's training MSE (the smallest), rung k passes when its held-out MSE is
    within 2 s^2 sqrt(2 / n_h) (two standard errors of a mean of n_h Gaussian
    squared residuals) of the best's. Returns (rung [P] int32, held-out MSE
    [K, P])."""
    K, P, C, L = err_h.shape
    n_h = np.maximum(seen.sum(1) * C, 1.0)
    mse = np.sum(err_h, axis=(2, 3)) / n_h
    s2 = np.min(sse_f.sum(2), axis=0) / np.maximum(n_f, 1.0)
    ok = mse <= (np.min(mse, axis=0) + 2.0 * s2 * np.sqrt(2.0 / n_h))[None]
    return np.argmax(ok, axis=0).astype(np.int32), mse


PER = ("region", "texel", "auto")


# A mean free path is resolved by a sample only where its profile sends at least
# this fraction of the diffused energy beyond the sample's own disc (radius
# sqrt(area / pi)); below it the data cannot tell that mean free path from a
# shorter one, however small the noise, and a pooled (per-region) 1-sigma
# would still look tight. Measured on `relight demo`'s head (2.6 mm texels,
# median sample): red (18% beyond the disc) 4% median error, green (4%) 39%,
# blue (0.2%) 50%.
MIN_SPREAD = 0.1


def spread_fraction(surface: stage.Surface, albedo, mfp) -> np.ndarray:
    """[P, C]: the fraction of each sample's Christensen-Burley profile energy
    (albedo [P, C], mean free path [P, C] mm, "dmfp") that lands beyond the
    sample's own disc of equal area (eq. 11's CDF at r = sqrt(area / pi))."""
    a = np.clip(np.nan_to_num(np.asarray(albedo, np.float64), nan=0.5), 0.01, 1.0)
    m = np.maximum(np.nan_to_num(np.asarray(mfp, np.float64)), 1e-4)
    prof = skin_bssrdf.Burley.from_mean_free_path(jnp.asarray(a), jnp.asarray(m), config="dmfp")
    rho = np.sqrt(np.asarray(surface.area, np.float64) / np.pi)
    tail = np.asarray(prof.tail(jnp.asarray(rho)), np.float64)
    total = np.asarray(prof.total(), np.float64)
    return tail / np.maximum(total, 1e-30)


def default_radius_mm(mfp_max: float, channels: int = 3) -> float:
    """The diffusion operator's neighbour radius (mm): 99% of the energy of the
    widest Burley profile a mean free path up to ``mfp_max`` (mm) gives (what
    :func:`relight.fit_subsurface` uses by default)."""
    widest = skin_bssrdf.Burley(jnp.full((channels,), 0.5), jnp.full((channels,), float(mfp_max) / 3.5))
    return float(np.max(np.asarray(skin_bssrdf.energy_radius(widest, 0.99))))


def fit_subsurface(capture: stage.Capture, surface: stage.Surface, fitted: Fit, *, per: str = "region", regions=None,
                   mfp_range=(0.05, 8.0), grid: int = 8, refine: int = 8, iterations: int = 2,
                   search_lights: int = 48, eta: float = 1.4, radius_mm: float | None = None,
                   max_neighbours: int | None = None, holdout: int = 5, max_steps: int = 48, progress=None) -> Fit:
    """Fit the subsurface rung: the diffuse mean free path (mm, per channel)
    and the profile albedo, given a BRDF ``fitted`` by :func:`relight.fit`
    (its specular lobe and normals are kept). docs/fit.md, "Subsurface" and
    "Per-texel subsurface".

    ``per``: "region" (default): one mean free path per region and channel
    (``regions``: int labels [P], default one region) by a 1-D grid +
    golden-section search, albedo in closed form per sample; a region switches
    to the subsurface rung only if that lowers its squared residual by more
    than two standard errors of the noise (s^2 sqrt(2 n) for n observations),
    else it keeps the fit's local Lambert term (mfp 0). "texel": from the
    region fit, every texel's (mfp, albedo) per channel jointly by
    Optimistix's Dogleg through the diffusion operator (the problem is
    separable per texel: ``_subsurface_texel``), with a weak prior of ln mfp
    toward the region's value (``PRIOR_SIGMA_LN_MFP``); texels with fewer than 8
    valid observations keep the region's. "auto": the ladder local Lambert <
    per-region < per-texel, chosen per texel on held-out lights (every
    ``holdout``-th light), the simplest rung within two standard errors of the
    noise of the best, then refitted on every light; ``Fit.heldout`` becomes
    the chosen rung's held-out RMS (capture units).

    ``mfp_range``: the bracket (mm). ``search_lights``: the mean-free-path
    searches (grid and texel solve) use that many lights spread over the rig;
    the final albedo, residuals and uncertainties use all (of the training
    lights, for "auto"'s trials). ``radius_mm``: the operator's neighbour
    radius (default: 99% of the energy of the widest profile searched).
    ``max_steps``: solver steps per texel (in rounds of 16). ``holdout``: for
    "auto". ``progress(phase, done, total)`` (``stage.Progress``): "fit
    subsurface" counts the region search's evaluations, "fit subsurface
    texels" the texels solved; "auto" runs each first as "... (held out)".

    Returns a new ``Fit``: ``mfp`` [P, 3] (0 where no subsurface), ``rho_d`` =
    the profile albedo and ``model`` = SUBSURFACE where ``mfp_rung`` > 0,
    ``mfp_sigma`` [P, 3] (1-sigma of ln mfp; inf where not identifiable: too
    few observations, or a profile that keeps more than 1 - ``MIN_SPREAD`` of
    its energy inside the sample's own disc) and
    ``mfp_rung`` [P] (0 none, 1 region, 2 texel).
    """
    V, L, P, C = capture.radiance.shape
    if per not in PER:
        raise ValueError(f"fit_subsurface: per must be one of {PER}, got {per!r}")
    if surface.num_samples != P or fitted.rho_d.shape[0] != P:
        raise ValueError(f"fit_subsurface: capture ({P}), surface ({surface.num_samples}) and fit "
                         f"({fitted.rho_d.shape[0]}) must have the same samples")
    lo, hi = (float(x) for x in mfp_range)
    if not 0 < lo < hi:
        raise ValueError(f"fit_subsurface: mfp_range must be 0 < lo < hi, got {mfp_range}")
    labels = np.zeros(P, np.int64) if regions is None else np.asarray(regions)
    if labels.shape != (P,) or not np.issubdtype(labels.dtype, np.integer) or labels.min() < 0:
        raise ValueError(f"fit_subsurface: regions must be non-negative int labels of shape [{P}]")
    if per == "auto" and not (isinstance(holdout, int) and 2 <= holdout <= L):
        raise ValueError(f"fit_subsurface: holdout must be an int in [2, {L}] (every holdout-th light), "
                         f"got {holdout!r}")
    if not (isinstance(max_steps, int) and max_steps >= 1):
        raise ValueError(f"fit_subsurface: max_steps must be an int >= 1, got {max_steps!r}")
    R = int(labels.max()) + 1
    dt = jnp.result_type(float)
    y, mask, E, wo, lam = _terms(capture, surface, fitted, eta)
    if radius_mm is None:
        radius_mm = default_radius_mm(hi, C)
    op = skin_bssrdf.DiffusionOperator.build(np.asarray(surface.position), np.asarray(surface.area), radius_mm,
                                             max_neighbours=max_neighbours)
    valid = mask
    vm = valid[..., None].astype(np.float64)  # [V, L, P, 1]
    data, unit = _reduced(y, valid, E, wo, eta, dt)
    geo = _tx.Geometry.of(op, dt)
    wo_b = jnp.asarray(wo)[:, None]  # [V, 1, P, 3] against the lights
    A_start = np.clip(np.asarray(fitted.rho_d, np.float64), 0.01, 1.0)
    every_l = np.arange(L)
    ones = np.ones((P, L))
    n_obs = np.sum(valid, axis=(0, 1))
    search_of = lambda ls: ls[np.unique(np.linspace(0, len(ls) - 1, min(search_lights, len(ls))).round().astype(int))]  # noqa: E731

    def region(lights, phase):
        bar = stage.Phase(progress, phase, iterations * (grid + refine))
        return _region_search(y, vm, E, wo_b, op, labels, R, lo, hi, grid, refine, iterations, search_of(lights),
                              lights, A_start, bar, eta)

    def region_scores(mfp_r, A, wf, wh):
        """Uncertainty and scores of the region rung at (mfp_r [R, C], A [P, C]), albedo kept."""
        return _tx.eval_texels(E, data, geo, unit, np.arange(P), every_l, wf, wh, np.log(mfp_r[labels]), A, dt=dt,
                               closed_albedo=False)

    def texel(lights, texels, ln_m0, A0, prior, wf, wh, phase):
        """The texel solve on the search subset of ``lights``, then the albedo and scores on all of ``lights`` (wf)."""
        bar = stage.Phase(progress, phase, len(texels))
        sub = search_of(lights)
        ln_m, A, code, _ = _tx.fit_texels(E, data, geo, unit, texels, sub, ones[:, sub], ln_m0, A0, prior, lo, hi,
                                          dt=dt, max_steps=max_steps, bar=bar)
        full_m = np.array(ln_m0)
        full_a = np.array(A0)
        full_m[texels], full_a[texels] = ln_m, A
        ev = _tx.eval_texels(E, data, geo, unit, texels, every_l, wf, wh, full_m, full_a, dt=dt, closed_albedo=True)
        return ln_m, ev

    rung = np.zeros(P, np.int32)
    mfp = np.zeros((P, C))
    sigma = np.full((P, C), np.inf)
    A_out = np.asarray(fitted.rho_d, np.float64).copy()
    heldout = np.asarray(fitted.heldout)
    if per == "region":
        mfp_r, A, sse_p = region(every_l, "fit subsurface")
        # Model choice per region: subsurface only where it explains the data better than noise can.
        r_local = vm * (y - np.asarray(fitted.rho_d, np.float64)[None, None] * lam)
        sse_local_p = np.sum(r_local * r_local, axis=(0, 1))
        sse_local = np.stack([np.bincount(labels, sse_local_p[:, c], minlength=R) for c in range(C)], 1).sum(1)
        sse = np.stack([np.bincount(labels, sse_p[:, c], minlength=R) for c in range(C)], 1)
        n = np.bincount(labels, n_obs * C, minlength=R).astype(np.float64)
        s2 = sse.sum(1) / np.maximum(n, 1.0)
        chosen = ((sse_local - sse.sum(1)) > 2.0 * s2 * np.sqrt(2.0 * np.maximum(n, 1.0)))[labels]
        sig_r = _region_sigma(region_scores(mfp_r, A, ones, 0 * ones)["info"], labels, R)
        rung[chosen] = 1
        mfp[chosen] = mfp_r[labels][chosen]
        sigma[chosen] = sig_r[labels][chosen]
        A_out[chosen] = A[chosen]
    else:
        if per == "auto":
            # Trials on the training lights, scored on every holdout-th light (as relight.fit's model="auto").
            hold = (every_l % holdout) == holdout // 2
            train_l = every_l[~hold]
            wt = np.broadcast_to(~hold, (P, L)).astype(np.float64)
            wh = 1.0 - wt
            mfp_t, A_t, _ = region(train_l, "fit subsurface (held out)")
            reg = _tx.eval_texels(E, data, geo, unit, np.arange(P), every_l, wt, wh, np.log(mfp_t[labels]), A_t,
                                  dt=dt, closed_albedo=True)
            prior = np.log(mfp_t[labels])
            ln_tex, tex = texel(train_l, np.arange(P), prior, reg["A"], prior, wt, wh,
                                "fit subsurface texels (held out)")
            lam_f, lam_h = _lambert_scores(y, vm, lam, (~hold).astype(np.float64), hold.astype(np.float64))
            # Valid views per held-out light count as observations (n_h).
            seen = np.sum(valid, axis=0).T * hold[None]
            n_f = np.sum(valid[:, ~hold], axis=(0, 1)) * C
            choice, hm = _ladder_choice(np.stack([lam_h, reg["err_h"], tex["err_h"]]),
                                        np.stack([lam_f, reg["sse_f"], tex["sse_f"]]), seen, n_f)
            heldout = np.sqrt(hm[choice, np.arange(P)])
            # The local rung keeps the fitted lobe with the albedo its trial scored, solved on every light
            # (after a joint pass the fit's own rho_d is what was left beside the predicted subsurface).
            none = choice == 0
            A_out[none] = _lambert_albedo(y, vm, lam, np.ones(L))[none]
            ln_start, A_tex = ln_tex, tex["A"]
        else:
            choice = np.where(n_obs >= _tx.MIN_OBSERVATIONS, 2, 1).astype(np.int32)
            ln_start = A_tex = None
        mfp_r, A, _ = region(every_l, "fit subsurface")
        reg = region_scores(mfp_r, A, ones, 0 * ones)
        sig_r = _region_sigma(reg["info"], labels, R)
        prior = np.log(mfp_r[labels])
        on = choice == 1
        rung[on] = 1
        mfp[on] = mfp_r[labels][on]
        sigma[on] = sig_r[labels][on]
        A_out[on] = A[on]
        tx = np.nonzero(choice == 2)[0]
        if len(tx):
            ln0 = prior if ln_start is None else np.where((choice == 2)[:, None], ln_start, prior)
            A0 = A if A_tex is None else np.where((choice == 2)[:, None], A_tex, A)
            ln_m, ev = texel(every_l, tx, ln0, A0, prior, ones, 0 * ones, "fit subsurface texels")
            rung[tx] = 2
            mfp[tx] = np.exp(ln_m)
            sigma[tx] = ev["sigma"]
            A_out[tx] = ev["A"]
    if per == "auto":
        heldout = np.nan_to_num(heldout, nan=0.0, posinf=0.0)
    sub_on = rung > 0
    # Resolved only where the profile spreads beyond the texel at the smaller of the texel's and its region's
    # mean free path: a texel estimate pushed up by model error must not certify itself (measured on the
    # demo's head: green texel estimates 3x their region's with sigma 0.03, 145% off the truth).
    m_test = np.minimum(mfp, mfp_r[labels])
    sigma = np.where(sub_on[:, None] & (spread_fraction(surface, A_out, m_test) < MIN_SPREAD), np.inf, sigma)
    model = np.where(sub_on, SUBSURFACE, np.asarray(fitted.model))
    fdt = fitted.rho_d.dtype
    A_out = np.where(n_obs[:, None] > 0, A_out, np.asarray(fitted.rho_d))
    # Every other field of the BRDF fit is carried over as it is (whatever fields Fit has).
    return dataclasses.replace(
        fitted, rho_d=jnp.asarray(np.nan_to_num(A_out), fdt), model=jnp.asarray(model, jnp.int32),
        heldout=jnp.asarray(heldout, fitted.heldout.dtype), mfp=jnp.asarray(np.where(sub_on[:, None], mfp, 0.0), fdt),
        mfp_sigma=jnp.asarray(np.where(np.isnan(sigma), np.inf, sigma), fdt), mfp_rung=jnp.asarray(rung, jnp.int32))

"""Lobes the lights never sampled, taken from the neighbours (``model="auto"``).

The ladder gives a sample no lobe when its lights show none. Where some light's half vector came within
the lobe's half maximum of the normal, that is a measurement: the surface there has no lobe the lights could
see. Where none did (the rig's lights sit on one side, the sample faces away from every camera-light mirror
pair), the data say nothing about the lobe, and Lambert is not an answer but an absence of one: relighting
then weighs exactly the directions no light sampled. Materials vary slowly over a surface, so such a sample
takes the microfacet lobe of its neighbours: the median F0 and roughness of the GGX samples among its nearest
fitted samples, its albedo refitted under that lobe (linear least squares), kept only if its own observations
are predicted at least as well as by Lambert. Its lobe parameters are reported unknown
(sigma inf: ``Fit.lobe_unmeasured``, ``Fit.unidentified``): a prior, not a measurement (docs/fit.md, "How",
item 8).

The search runs over the whole fit's maps, after every block, so the result does not depend on the block
size; the observations of the samples it changes are read again, a block at a time.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

import stage

from ..materials._maps import GGX, GGX_ANISO, LAMBERT
from . import _model as _fit_model
from ._devices import _chunks_of
from ._extrapolation import peak_sampled
from ._model import Layout
from ._observations import _normalise, _obs_bucket, _observations_of
from ._result import FIELDS, MIN_OBSERVATIONS, Fit, fit_from_arrays
from ._shadows import cast_shadow
from ._sources import read_block

# A sample takes its neighbours' lobe when at least NEIGHBOURS of its NEIGHBOURHOOD nearest fitted samples
# have a measured microfacet lobe (a quarter: the lobe is the neighbourhood's, not a far region's).
NEIGHBOURS = 16
NEIGHBOURHOOD = 4 * NEIGHBOURS


def _neighbour_lobes(position, donor, fitted, target, rho_s, alpha):
    """Per target sample (indices ``target``): (has_lobe bool, F0, alpha): the median F0 and roughness
    (sqrt(alpha_x alpha_y)) of the ``donor`` samples among its NEIGHBOURHOOD nearest ``fitted`` samples
    (by world position), where at least NEIGHBOURS of them are donors."""
    from scipy.spatial import cKDTree

    pool = np.nonzero(fitted)[0]
    k = min(NEIGHBOURHOOD, len(pool))
    has = np.zeros(len(target), bool)
    f0 = np.zeros(len(target))
    al = np.zeros(len(target))
    if k < NEIGHBOURS:
        return has, f0, al
    tree = cKDTree(position[pool])
    rough = np.sqrt(np.prod(alpha, axis=1))
    for s in range(0, len(target), 1 << 14):  # the neighbour lists in slices: memory by the slice
        t = target[s:s + (1 << 14)]
        _, nn = tree.query(position[t], k=k)
        nn = pool[np.reshape(nn, (len(t), k))]
        is_d = donor[nn]
        ok = np.sum(is_d, axis=1) >= NEIGHBOURS
        if not ok.any():
            continue
        mask = is_d[ok]
        has[s:s + len(t)] = ok
        f0[s:s + len(t)][ok] = np.nanmedian(np.where(mask, rho_s[nn[ok]], np.nan), axis=1)
        al[s:s + len(t)][ok] = np.nanmedian(np.where(mask, rough[nn[ok]], np.nan), axis=1)
    return has, f0, al


@jax.jit(static_argnames=("floor", "shadow_ratio"))
def _under_lobe_chunk(obs, w, wi, wo, irr, rho_l, f0, alpha, floor: float, shadow_ratio: float | None):
    """Per sample (directions in its fitted frame): the albedo refitted under the lobe (F0, alpha) by
    linear least squares per channel, clipped to [0, 1]; the mean squared residual with it and with the
    Lambert albedo ``rho_l``; whether the lights sampled the lobe's peak
    (:func:`relight.fitting._extrapolation.peak_sampled`). With the fit's ``shadow_ratio``, the observations
    Lambert's prediction calls cast shadows are left out (:func:`relight.fitting._shadows.cast_shadow`,
    all kept where fewer than ``MIN_OBSERVATIONS`` would remain), as the fit left them out."""
    lay = Layout(GGX, False, floor)

    def one(obs, w, wi, wo, irr, rho_l, f0, alpha):
        up = jnp.asarray([0.0, 0.0, 1.0], obs.dtype)
        base = dict(normal=up, phi=jnp.zeros((), obs.dtype), rho_s=jnp.reshape(f0, (1,)),
                    alpha=jnp.stack([alpha, alpha]))
        lobe = _fit_model.predict(dict(base, rho_d=jnp.zeros(3, obs.dtype)), lay, wi, wo, irr)
        # The radiance of a white Lambertian surface: the prediction is linear in the albedo.
        white = _fit_model.predict(dict(base, rho_d=jnp.ones(3, obs.dtype), rho_s=jnp.zeros(1, obs.dtype)),
                                   Layout(LAMBERT, False, floor), wi, wo, irr)
        if shadow_ratio is not None:
            cut = cast_shadow(obs, rho_l[None] * white, w, shadow_ratio)
            enough = jnp.sum(w[:, 0] > 0) - jnp.sum(cut) >= MIN_OBSERVATIONS
            w = jnp.where((cut & enough)[:, None], 0.0, w)
        a = jnp.sum(w * white * white, axis=0)
        b = jnp.sum(w * (obs - lobe) * white, axis=0)
        rho = jnp.clip(b / jnp.maximum(a, 1e-30), 0.0, 1.0)
        n = jnp.maximum(jnp.sum(w), 1.0)
        mse = jnp.sum(w * (obs - lobe - rho[None] * white) ** 2) / n
        mse_l = jnp.sum(w * (obs - rho_l[None] * white) ** 2) / n
        return rho, mse, mse_l, peak_sampled(wi, wo, w[:, 0] > 0, alpha)

    return jax.vmap(one)(obs, w, wi, wo, irr, rho_l, f0, alpha)


def _fitted_frame_surface(surface: stage.Surface, index, normal, tangent) -> stage.Surface:
    """``surface``'s samples ``index`` with the fit's shading frame (world normal and tangent, the tangent
    made orthogonal to the normal): observations built on it have their directions in the fitted frame."""
    sub = surface.take(index)
    n = normal / np.linalg.norm(normal, axis=1, keepdims=True)
    t = tangent - np.sum(tangent * n, axis=1, keepdims=True) * n
    t = t / np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-12)
    dt = np.asarray(sub.normal).dtype
    return stage.Surface(position=sub.position, normal=jnp.asarray(n, dt), tangent=jnp.asarray(t, dt),
                         bitangent=jnp.asarray(np.cross(n, t), dt), uv=sub.uv, area=sub.area,
                         texel_index=sub.texel_index, face=sub.face, resolution=sub.resolution,
                         barycentric=sub.barycentric)


def lobes_from_neighbours(fitted: Fit, plan, surface: stage.Surface, progress=None) -> Fit:
    """``fitted`` with its Lambert samples whose lights never sampled a lobe given their neighbours' (module
    docstring). ``plan``: the fit's ``_Plan`` (its source, rig, cameras, block, chunk size, roughness
    floor, dtype and shadow ratio). Returns ``fitted`` itself when no sample changes."""
    f = {k: np.array(getattr(fitted, k)) for k in FIELDS}
    failed = np.asarray(fitted.failed, bool)
    model = f["model"]
    donor = ~failed & ((model == GGX) | (model == GGX_ANISO)) & ~np.asarray(fitted.collapsed, bool)
    target = np.nonzero(~failed & (model == LAMBERT))[0]
    if not donor.any() or len(target) == 0:
        return fitted
    has, f0, al = _neighbour_lobes(np.asarray(surface.position, np.float64), donor, ~failed, target,
                                   f["rho_s"][:, 0].astype(np.float64), f["alpha"].astype(np.float64))
    target, f0, al = target[has], f0[has], al[has]
    if len(target) == 0:
        return fitted
    bar = stage.Phase(progress, "lobes from neighbours", len(target))
    n_keep = _obs_bucket(int(np.max(f["observed"][target])))
    size, dt, changed = plan.opts["size"], plan.dt, False
    for b0 in range(0, plan.P, plan.block):
        b1 = min(b0 + plan.block, plan.P)
        here = np.nonzero((target >= b0) & (target < b1))[0]
        if len(here) == 0:
            continue
        rad, mask = read_block(plan.source, b0, b1)
        for idx, m in _chunks_of(here, size):
            t = target[idx]
            sub = _fitted_frame_surface(surface, t, f["normal"][t].astype(np.float64),
                                        f["tangent"][t].astype(np.float64))
            obs, w, wi, wo, irr, _ = _observations_of(rad[:, :, t - b0], mask[:, :, t - b0], plan.rig,
                                                      plan.cameras, sub, n_keep, dt)
            obs, irr, unit = _normalise(obs, w, irr)
            rho, mse, mse_l, seen = (np.asarray(x)[:m] for x in _under_lobe_chunk(
                *(jnp.asarray(x) for x in (obs, w, wi, wo, irr)), jnp.asarray(f["rho_d"][t], dt),
                jnp.asarray(f0[idx], dt), jnp.asarray(al[idx], dt), floor=float(plan.floor),
                shadow_ratio=plan.shadow_ratio))
            # No tolerance: the lent lobe has no parameters of the sample's own, so there is no parsimony to
            # trade accuracy for (the ladder's two standard errors); it is taken only where the sample's own
            # observations do not favour Lambert. With the tolerance, Extended Yale B subject 20's held-out
            # error rose 0.784x -> 0.798x the baseline (docs/fit.md, "How", item 8).
            keep = ~seen & (mse <= mse_l)
            s = t[:m][keep]
            if len(s):
                changed = True
                f["model"][s] = GGX
                f["rho_d"][s] = rho[keep]
                f["rho_s"][s, 0] = f0[idx[:m]][keep]
                f["alpha"][s] = al[idx[:m]][keep][:, None]
                f["uncertainty"][s, 3:5] = np.inf  # F0 and roughness: the neighbours', not measured here
                f["residual"][s] = np.sqrt(mse[keep]) * unit[:m][keep]
            bar.advance(m)
        del rad, mask
    if not changed:
        return fitted
    return fit_from_arrays(f, dt, fitted.alpha_floor, fitted.solver, fitted.min_observed)

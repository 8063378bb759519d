"""The model ladder: which rungs a fit tries, the held-out choice between them, and a block's
per-sample result assembled from the rungs' solves.

``model="auto"``: every rung is fitted on all but every ``holdout``-th of each sample's observations (ranked
from its mirror direction outward) and scored on those; each sample keeps the simplest rung (the fewest
parameters) whose prediction error, the held-out and the training estimates pooled, is within two standard
errors of the best (:func:`choose_rungs`), then is refitted on every light; a sample
whose refitted lobe is an extrapolated highlight (:mod:`relight.fitting._extrapolation`) goes one rung down.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..materials._maps import BLINN_PHONG, GGX, GGX_ANISO, LAMBERT, MODELS, SUBSURFACE
from . import _model as _fit_model
from ._devices import _chunks_of
from ._init import photometric_stereo
from ._model import Layout
from ._result import FIELDS


def _rungs(model) -> tuple[int, ...]:
    if model == "auto":
        return (LAMBERT, BLINN_PHONG, GGX, GGX_ANISO)
    if model not in MODELS or model == "subsurface":
        raise ValueError(f"fit: model must be 'auto' or one of {MODELS[:SUBSURFACE]} (subsurface: "
                         f"relight.fit_subsurface after a fit), got {model!r}")
    return (MODELS.index(model),)


@jax.jit
def _ps_normal_chunk(obs, w, wi, wo, irr):
    return jax.vmap(lambda *a: photometric_stereo(*a, True)[0])(obs, w, wi, wo, irr)


def specular_cosines(data, normals: bool, size: int) -> np.ndarray:
    """Each observation's cosine between its half vector and the sample's normal [n, N]: the normal
    from photometric stereo on the valid observations (:func:`relight.fitting._init.photometric_stereo`)
    when the fit fits normals, else the surface's. ``data``: the block's ``(obs, w, wi, wo, irr)``
    (surface-frame directions); ``size`` samples per call (padded: one program)."""
    obs, w, wi, wo, irr = data
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-12)
    if not normals:
        return h[..., 2]
    normal = np.zeros((len(obs), 3), h.dtype)
    for idx, m in _chunks_of(np.arange(len(obs)), size):
        part = _ps_normal_chunk(*(jnp.asarray(x[idx]) for x in data))
        normal[idx[:m]] = np.asarray(part)[:m]
    return np.einsum("nkc,nc->nk", h, normal)


def heldout_weights(w, cos_h, holdout: int):
    """The held-out observations' weights [n, N, C]: each sample's valid observations ``w`` ranked by
    how close their half vector is to the normal (``cos_h`` [n, N], :func:`specular_cosines`, highest
    first), every ``holdout``-th of them (ranks ``holdout // 2``, ``holdout // 2 + holdout``, ...).

    Why ranked: the rungs differ in the lobe, near the mirror direction. Held-out lights taken by index
    miss a highlight that covers one or two of a sample's lights, and the ladder then cannot tell a lobe
    from none (docs/fit.md, "How", item 8). Ranked, every ``holdout`` consecutive observations from the
    mirror direction outward lose one to the held-out set and keep the rest for training."""
    valid = np.any(w > 0, axis=-1)
    order = np.argsort(np.where(valid, -cos_h, np.inf), axis=1, kind="stable")
    rank = np.empty_like(order)
    np.put_along_axis(rank, order, np.arange(order.shape[1])[None], axis=1)
    held = valid & (rank % holdout == holdout // 2)
    return held[..., None].astype(w.dtype) * w


def choose_rungs(trial: dict, rungs, hmask, n_train, dt, normals: bool = False):
    """Each sample's rung from the held-out trials: (choice [n] int32, held-out RMS [n]).

    ``trial[k]``: rung k's solve on the training observations (``hmse`` [n], its held-out MSE; ``rms``
    [n], its training RMS); ``hmask``: :func:`heldout_weights`; ``n_train`` [n]: each sample's training
    observations; ``normals``: whether the rungs fit normals (two more parameters each).

    Each rung's prediction error is estimated twice and the two are pooled, weighted by their counts:
    the held-out MSE over the n_h held-out observations (unbiased), and the training MSE over the n_t
    training observations corrected for the p parameters fitted to them, Akaike's final prediction error
    MSE (n_t + p) / (n_t - p) (Akaike 1970, "Statistical predictor identification", Ann. Inst. Stat. Math.
    22). A rung is kept when its pooled estimate is within two standard errors of the best rung's: the
    mean of n squared Gaussian residuals of variance s^2 has a standard error of s^2 sqrt(2 / n), with s^2
    the smallest training MSE and n = n_h + n_t. Of the kept rungs, the simplest: the fewest parameters;
    of Blinn-Phong and GGX, which have as many, GGX when both are kept, else the kept one.

    Why GGX between equals: when both lobes predict the sample's lights within the noise, the lights do not
    say which shape the surface has, and the choice decides the directions they did not sample, which
    relighting weighs. The microfacet lobe (Walter et al. 2007) carries a surface's Fresnel, shadowing-masking
    and 1 / (4 cos theta_i cos theta_o) foreshortening; Blinn-Phong's normalised cosine power has none of them
    and falls short at grazing angles. On the Mitsuba head (a GGX material) the lower pooled estimate had
    put 9% of the texels on Blinn-Phong, carrying 70% of ``auto``'s relit squared error
    (docs/fit.md, "How", item 8).

    Why pooled (docs/fit.md, "How", item 8): a highlight that covers one or two of a sample's observations
    is rarely held out, so a rung without the lobe can predict the held-out observations as well as, or
    better than, the rung that fits the highlight, while it leaves the highlight in its training residual;
    and a rung that fits shadows or noise in training pays for it on the held-out observations.
    """
    hm = np.stack([trial[k]["hmse"] for k in rungs]).astype(np.float64)  # [K, n]
    tr = np.stack([trial[k]["rms"] ** 2 for k in rungs]).astype(np.float64)  # [K, n]
    n_h = np.maximum(np.sum(hmask[..., 0] > 0, axis=1), 1.0)
    n_t = np.maximum(np.asarray(n_train, np.float64), 1.0)
    size = np.asarray([Layout(k, normals, 0.5).size for k in rungs], np.float64)[:, None]
    fpe = tr * (n_t + size) / np.maximum(n_t - size, 1.0)
    pooled = (n_h * hm + n_t * fpe) / (n_h + n_t)
    s2 = np.min(tr, axis=0)
    ok = pooled <= (np.min(pooled, axis=0) + 2.0 * s2 * np.sqrt(2.0 / (n_h + n_t)))[None]
    # Simplest = fewest parameters. Blinn-Phong and GGX have as many (an albedo and a roughness), so neither is
    # simpler: when both are kept the data cannot tell them apart, and GGX, the microfacet lobe, is kept (why:
    # docstring). Blinn-Phong only where GGX is not within the tolerance.
    fewest = ok & (size == np.min(np.where(ok, size, np.inf), axis=0))
    if BLINN_PHONG in rungs and GGX in rungs:
        fewest[list(rungs).index(BLINN_PHONG)] &= ~fewest[list(rungs).index(GGX)]
    pick = np.argmin(np.where(fewest, pooled, np.inf), axis=0)
    choice = np.asarray(rungs, np.int32)[pick]
    heldout = np.sqrt(hm[pick, np.arange(hm.shape[1])]).astype(dt)
    return choice, heldout


def finish_block(out, n_valid, block_surface, unit, heldout, choice, dt, min_observed: int) -> dict:
    """A block's Fit fields (``FIELDS``) from :func:`_assemble`'s ``out``:
    samples with fewer than ``min_observed`` valid observations get grey
    defaults and every parameter of their rung unknown (sigma inf); NaN is
    replaced (parameters 0, sigma inf, residual the largest float); the RMS
    residual and held-out RMS are scaled back by ``unit`` [n] to the
    capture's radiance units. Shared by :func:`fit` and
    :func:`relight.fitting.fit_patterns`."""
    nobs = n_valid.astype(np.float32)
    empty = nobs < min_observed
    # A sample with no usable data gets grey defaults instead of whatever the solver made of zeros.
    out["rho_d"][empty] = 0.5
    out["rho_s"][empty] = 0.04
    out["alpha"][empty] = 0.3
    out["normal"][empty] = np.asarray(block_surface.normal, dt)[empty]
    out["tangent"][empty] = np.asarray(block_surface.tangent, dt)[empty]
    # No usable data: every parameter the sample's rung has is unknown.
    unc = out["uncertainty"]
    unc[empty] = np.where((unc[empty] != 0) | (np.arange(9) < 3), np.inf, 0.0)
    big = np.finfo(np.float32).max
    for k in ("rho_d", "rho_s", "alpha"):
        out[k] = np.nan_to_num(out[k], nan=0.0, posinf=0.0, neginf=0.0)
    out["uncertainty"] = np.nan_to_num(unc, nan=np.inf, posinf=np.inf, neginf=np.inf)
    # Residuals back in the capture's radiance units.
    out["residual"] = np.nan_to_num(out["residual"] * unit.astype(dt), nan=big, posinf=big)
    out["heldout"] = np.nan_to_num(heldout * unit.astype(dt))
    out["model"] = choice
    out["observed"] = nobs
    return {k: out[k] for k in FIELDS}


def _assemble(fits, choice, P, normals, floor, dt, surface, size):
    out = dict(rho_d=np.zeros((P, 3), dt), rho_s=np.zeros((P, 1), dt), alpha=np.zeros((P, 2), dt),
               normal=np.zeros((P, 3), dt), tangent=np.zeros((P, 3), dt), residual=np.zeros(P, dt),
               result=np.zeros(P, np.int32), steps=np.zeros(P, np.int32), uncertainty=np.zeros((P, 9), dt))
    T, B, N = (np.asarray(x, np.float64) for x in (surface.tangent, surface.bitangent, surface.normal))
    for k, (sel, r) in fits.items():
        lay = Layout(k, normals, floor)
        p, R = _physical(r["u"], lay, size)
        out["rho_d"][sel] = p["rho_d"]
        out["rho_s"][sel] = p["rho_s"]
        out["alpha"][sel] = p["alpha"]
        # Fitted frame (surface-frame coordinates) to world space.
        R = R.astype(np.float64)
        t_l, n_l = R[:, 0], R[:, 2]
        Ts, Bs, Ns = T[sel], B[sel], N[sel]
        to_world = lambda v, Ts=Ts, Bs=Bs, Ns=Ns: v[:, 0:1] * Ts + v[:, 1:2] * Bs + v[:, 2:3] * Ns  # noqa: E731
        out["normal"][sel] = to_world(n_l)
        out["tangent"][sel] = to_world(t_l)
        out["residual"][sel] = r["rms"]
        out["result"][sel] = r["code"]
        out["steps"][sel] = r["steps"]
        out["uncertainty"][np.ix_(sel, _union_index(lay))] = r["sigma"]
    return out


def _union_index(lay: Layout) -> list[int]:
    """Where each of a rung's physical parameters goes in PARAM_NAMES."""
    idx = [0, 1, 2]
    if lay.model >= BLINN_PHONG:
        idx += [3, 4]
    if lay.model >= GGX_ANISO:
        idx += [5, 6]
    if lay.normals:
        idx += [7, 8]
    return idx


@jax.jit(static_argnames=("lay",))
def _physical_chunk(u, lay):
    p = jax.vmap(lambda v: _fit_model.unpack(v, lay))(u)
    return p, jax.vmap(_fit_model.frame)(p["normal"], p["phi"])


def _physical(u, lay, size):
    """A rung's u [n, lay.size] unpacked to NumPy physical maps and the fitted frames R [n, 3, 3]
    (surface-frame coordinates), ``size`` samples per call (padded: one program per rung)."""
    parts = [_physical_chunk(jnp.asarray(u[idx]), lay) for idx, _ in _chunks_of(np.arange(len(u)), size)]
    p, R = jax.tree_util.tree_map(lambda *x: np.concatenate([np.asarray(a) for a in x])[:len(u)], *parts)
    return p, R

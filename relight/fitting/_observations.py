"""A block of samples' observations, packed for the solver.

Per sample, every (view, light) the capture marks valid becomes one observation of C channels with
its local directions wi, wo and irradiance (``stage.shading_directions``); the valid ones come first
and the rest is padding of weight 0, to one padded count (:func:`_obs_bucket`) for the whole fit so
each rung's solver compiles once. :func:`_normalise` divides each sample's radiance and irradiance
by its RMS irradiance (docs/fit.md, "Units and scale").
"""

from __future__ import annotations

import numpy as np

import stage

from ._sources import read_block


def _obs_bucket(n: int) -> int:
    """The padded observation count for a capture whose richest sample has ``n``: the smallest of 32,
    64, 96, 128, 192, 256, 384, 512, 768, ... (multiples of 32 up to 128, then 1 or 1.5 times a power of
    two) that holds it. Coarse buckets let captures of other sizes and coverage reuse the compiled
    solver (each rung's program is specialised to this count); the padding (w = 0) costs at most a third
    more work per step beyond 128 observations."""
    n = max(int(n), 1)
    if n <= 128:
        return -(-n // 32) * 32
    b = 128
    while b < n:
        b = b * 3 // 2 if (b & (b - 1)) == 0 else b * 4 // 3
    return b


def _normalise(obs, w, irr):
    """(obs / E, irr / E, E [P]) for each sample's irradiance scale E, the RMS
    of its irradiance at normal incidence over its valid observations (1 for
    a sample without any). Dividing the observations and the irradiance by
    one number leaves every parameter unchanged (the model is linear in the
    irradiance) and makes the solver's problem that of a rig of irradiance
    ~1: radiance per unit irradiance, the scale of f_r cos (albedo / pi), in
    any capture or rig units. So Optimistix's ``atol``, its initial damping,
    the Cauchy scale's floor, the accept test and the start's floors are
    relative, not in the capture's units; a change of units (rig and radiance
    x k) is an exact symmetry of the normalised problem. For distant lights
    of irradiance 1 (``stage.geodesic_dome()``) E is exactly 1."""
    wv = w[..., 0].astype(np.float64)
    i2 = np.sum(wv[..., None] * np.square(irr, dtype=np.float64), axis=(1, 2))
    n = irr.shape[-1] * np.sum(wv, axis=1)
    unit = np.sqrt(np.where(n > 0, i2 / np.maximum(n, 1.0), 1.0))
    unit = np.where(np.isfinite(unit) & (unit > 0), unit, 1.0)
    inv = (1.0 / unit)[:, None, None]
    return (obs * inv).astype(obs.dtype), (irr * inv).astype(irr.dtype), unit


def _observations(source, surface, s, e, n_keep, dt):
    """Per-sample observation arrays [e - s, n_keep, ...] for samples s..e of a
    ``relight.io.CaptureSource``: radiance, weights (1 valid / 0 padding), wi,
    wo (local), irradiance and the light index of each observation."""
    rad, mask = read_block(source, s, e)
    return _observations_of(rad, mask, source.stage_rig(), source.stage_cameras(), surface.take(np.arange(s, e)),
                            n_keep, dt)


def _observations_of(radiance, mask, rig, cameras, sub, n_keep, dt):
    """:func:`_observations` of samples already read: ``radiance`` [V, L, n, C], ``mask`` [V, L, n]
    and their surface ``sub`` (n samples)."""
    n = sub.num_samples
    obs_v, w_v, wi_v, wo_v, irr_v, li_v = [], [], [], [], [], []
    L = rig.num_lights
    for v, cam in enumerate(cameras):
        wi, wo, irr = stage.shading_directions(sub, rig, cam)
        obs_v.append(np.swapaxes(np.asarray(radiance[v], np.float32), 0, 1))
        w_v.append(np.swapaxes(np.asarray(mask[v]), 0, 1))
        wi_v.append(np.swapaxes(np.asarray(wi), 0, 1))
        wo_v.append(np.broadcast_to(np.asarray(wo)[:, None], wi_v[-1].shape))
        irr_v.append(np.swapaxes(np.asarray(irr), 0, 1))
        li_v.append(np.broadcast_to(np.arange(L)[None], (n, L)))
    cat = lambda xs: np.concatenate(xs, axis=1)  # noqa: E731  [n, V*L, ...]
    obs, wmask, wi, wo, irr, li = cat(obs_v), cat(w_v), cat(wi_v), cat(wo_v), cat(irr_v), cat(li_v)
    # Keep only valid observations (valid first, then padding): typically
    # half of a rig's lights are behind a sample.
    order = np.argsort(~wmask, axis=1, kind="stable")[:, :n_keep]
    if order.shape[1] < n_keep:  # fewer observations than the rounded-up count: pad with invalid ones
        order = np.concatenate([order, np.repeat(order[:, -1:], n_keep - order.shape[1], axis=1)], axis=1)
    take = lambda a: np.take_along_axis(a, order.reshape(order.shape + (1,) * (a.ndim - 2)), axis=1)  # noqa: E731
    obs, wm, wi, wo, irr, li = take(obs), take(wmask), take(wi), take(wo), take(irr), take(li)
    wm[:, wmask.shape[1]:] = False  # the repeated padding columns, if any
    w = np.broadcast_to(wm[..., None], obs.shape).astype(dt)
    return obs.astype(dt), w, wi.astype(dt), wo.astype(dt), irr.astype(dt), li

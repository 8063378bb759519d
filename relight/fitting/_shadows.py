"""Cast shadows the model does not have: observations far darker than a first fit predicts, censored
before a second fit (``relight.fit(..., shadow_ratio=...)``; docs/fit.md, "How", item 4).

The fitter's models light every observation whose light is above the fitted normal's horizon (attached
shadows are in the model: cos_i clipped at 0). A cast shadow (a fold, an ear, a nostril between the point
and the light) or an occluding neighbour is not: the observation then carries only the indirect light and
reads a small fraction of what the model predicts. Shadows only darken, so such an observation is
recognised by its ratio to the first fit's prediction. The lights of a light stage and of DiLiGenT are
small (LEDs, a few mm at a metre and more): a point sees the whole source or none of it, outside a thin
penumbra, so the ratio of a shadowed observation to the direct-light prediction is near 0 (the indirect
light) and that of a lit one near 1 (the model's error). The threshold between the two outcomes is taken
midway, ``SHADOW_RATIO`` = 1/2: an observation that receives less than half the predicted direct light is
more likely occluded than lit. Censoring (weight 0) rather than down-weighting: under a robust loss a
shadowed observation still pulls with the loss's tail; with it removed, the refit sees the
lit observations only.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from . import _model as _fit_model
from ._devices import _chunks_of
from ._model import Layout

# The fraction of the predicted radiance below which an observation counts as cast-shadowed: midway
# between fully occluded (about 0, the indirect light) and lit (1, up to the model's error) for a
# small light (module docstring). Not tuned: on DiLiGenT's cat (Blinn-Phong, Cauchy) 0.3, 0.5 and 0.7 give
# mean normal errors within 0.02 deg of each other (docs/fit.md, "How", item 4).
SHADOW_RATIO = 0.5


def cast_shadow(obs, pred, w, ratio):
    """bool [..., N]: the valid observations (``w`` [..., N, C] > 0) whose grey value (the sum of the
    channels of ``obs`` [..., N, C]) is below ``ratio`` x the prediction ``pred``'s (module docstring)."""
    return (w[..., 0] > 0) & (jnp.sum(obs, axis=-1) < ratio * jnp.sum(pred, axis=-1))


@jax.jit(static_argnames=("lay",))
def _shadowed_chunk(u, obs, w, wi, wo, irr, ratio, lay: Layout):
    """bool [Pc, N]: the valid observations whose grey value (sum of channels) is below ``ratio`` x
    the rung's prediction from the fitted parameters ``u`` (sample-major arrays)."""

    def one(u, obs, w, wi, wo, irr):
        return cast_shadow(obs, _fit_model.predict(_fit_model.unpack(u, lay), lay, wi, wo, irr), w, ratio)

    return jax.vmap(one)(u, obs, w, wi, wo, irr)


def shadowed(u, lay: Layout, data, index, ratio: float, size: int, min_kept: int) -> np.ndarray:
    """Which observations of the samples ``index`` read below ``ratio`` x the fitted prediction: the
    cast shadows to censor (module docstring).

    Args:
        u: the rung's fitted unconstrained parameters over ``index`` [len(index), lay.size].
        lay: the rung's ``Layout``.
        data: the block's ``(obs, w, wi, wo, irr)`` (normalised; surface-frame directions), sample-major
            [n, N, ...].
        index: the block's samples that ``u`` belongs to.
        ratio: the threshold, a fraction of the predicted radiance in (0, 1) (``SHADOW_RATIO``).
        size: samples per call (padded: one program per rung).
        min_kept: a sample keeps all its observations when censoring would leave it fewer than this
            many valid ones (its fit would no longer be determined).

    Returns:
        bool [len(index), N], True where the observation is to be censored.
    """
    obs, w = data[0], data[1]
    out = np.zeros((len(index), obs.shape[1]), bool)
    if len(index) == 0:
        return out
    for idx, n in _chunks_of(np.arange(len(index)), size):
        args = [jnp.asarray(x[index[idx]]) for x in data]
        flags = _shadowed_chunk(jnp.asarray(u[idx]), *args, jnp.asarray(ratio, obs.dtype), lay=lay)
        out[idx[:n]] = np.asarray(flags)[:n]
    kept = np.sum(w[index, :, 0] > 0, axis=1) - np.sum(out, axis=1)
    out[kept < min_kept] = False
    return out

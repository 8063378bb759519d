"""Highlights the lights never saw: a lobe whose peak falls between the lights and predicts more than
any observation.

A sample's fitted lobe is pinned down where lights fall within its half maximum. When none does, the
peak's height is not measured but extrapolated from the lobe's flanks, and height and width trade
against each other: on real faces (Extended Yale B) a GGX lobe at the roughness floor with F0 near 1,
its peak in a gap of the rig, predicts 10-15 times the brightest observation of its pixel at the
held-out light that falls there. ``model="auto"`` does not keep such a rung (docs/fit.md, "How",
item 8).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..materials._maps import BLINN_PHONG, LadderBRDF
from . import _model as _fit_model
from ._devices import _chunks_of
from ._model import Layout

# A GGX lobe falls to half its peak 0.64 alpha from it in the half vector (D ~ (alpha^2 + theta_h^2)^-2).
HALF_MAX_HALF_ANGLE = 0.64
# The predicted peak counts as extrapolated beyond the data above this multiple of the sample's brightest
# valid observation (docs/fit.md, "How", item 8: 1, 2 and 4 measured on Yale B and DiLiGenT).
EXTRAPOLATION_FACTOR = 4.0


def peak_sampled(wi, wo, valid, alpha):
    """Whether the lights sampled a lobe's peak: some ``valid`` [N] observation's half vector (``wi``, ``wo``
    [N, 3] in the fitted frame, z the normal) lies within the lobe's half maximum of the normal,
    HALF_MAX_HALF_ANGLE x ``alpha`` (the roughness, sqrt(alpha_x alpha_y)). Shared by this module and
    :mod:`relight.fitting._neighbours`."""
    h = wi + wo
    cos_h = h[:, 2] / jnp.maximum(jnp.linalg.norm(h, axis=-1), 1e-12)
    return jnp.any(valid & (cos_h >= jnp.cos(HALF_MAX_HALF_ANGLE * alpha)))


@jax.jit(static_argnames=("lay",))
def _extrapolated_chunk(u, obs, w, wi, wo, irr, lay: Layout):
    def one(u, obs, w, wi, wo, irr):
        p = _fit_model.unpack(u, lay)
        R = _fit_model.frame(p["normal"], p["phi"])  # rows t, b, n in the surface frame
        wi_f, wo_f = wi @ R.T, wo @ R.T  # [N, 3] in the fitted frame
        valid = w[:, 0] > 0
        seen = peak_sampled(wi_f, wo_f, valid, jnp.sqrt(p["alpha"][0] * p["alpha"][1]))
        # The lobe's radiance at its peak for each observation's view (the light at wo's mirror
        # direction, at the sample's strongest irradiance), without the diffuse term.
        peak_dir = wo_f * jnp.asarray([[-1.0, -1.0, 1.0]], wo_f.dtype)
        N = wo_f.shape[0]
        per_obs = lambda x: jnp.broadcast_to(x, (N, x.shape[-1]))  # noqa: E731  brdf: parameters [N, k]
        lobe = LadderBRDF(jnp.zeros((N, 3), wo_f.dtype), per_obs(p["rho_s"]), per_obs(p["alpha"]),
                          jnp.full((N, 1), lay.model, jnp.int32))(peak_dir, wo_f)  # [N, 3], no diffuse
        e_max = jnp.max(jnp.where(valid[:, None], irr, 0.0), axis=0, keepdims=True)
        peak = jnp.max(jnp.where(valid[:, None], lobe * peak_dir[:, 2:3] * e_max, 0.0))
        bright = jnp.max(jnp.where(w > 0, obs, 0.0))
        return ~seen & (peak > EXTRAPOLATION_FACTOR * bright)

    return jax.vmap(one)(u, obs, w, wi, wo, irr)


def extrapolated_highlights(u, lay: Layout, data, index, size: int) -> np.ndarray:
    """Which samples' fitted lobes are extrapolated highlights, bool [len(index)].

    A sample's lobe is extrapolated when no valid observation's half vector lies within the lobe's half
    maximum of the fitted normal (0.64 sqrt(alpha_x alpha_y): the lights never sampled the peak) and the
    lobe's radiance at its peak, for a light at the mirror direction of one of the sample's views at its
    strongest irradiance, exceeds ``EXTRAPOLATION_FACTOR`` times the sample's brightest valid
    observation. Lambert has no lobe: never extrapolated.

    Args:
        u: the rung's fitted unconstrained parameters over ``index`` [len(index), lay.size].
        lay: the rung's ``Layout``.
        data: the block's ``(obs, w, wi, wo, irr)`` (normalised; surface-frame directions).
        index: the block's samples that ``u`` belongs to.
        size: samples per call (padded: one program per rung).

    Returns:
        The flags, in the order of ``index``.
    """
    out = np.zeros(len(index), bool)
    if lay.model < BLINN_PHONG or len(index) == 0:
        return out
    local = np.arange(len(index))
    for idx, n in _chunks_of(local, size):
        args = [jnp.asarray(x[index[idx]]) for x in data]
        flags = _extrapolated_chunk(jnp.asarray(u[idx]), *args, lay=lay)
        out[idx[:n]] = np.asarray(flags)[:n]
    return out

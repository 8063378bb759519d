"""Per-sample reflectance fitting with Optimistix (Levenberg-Marquardt).

Model (Kang et al. 2018's Lambert + GGX form): f_r = rho_d / pi + D F G /
(4 cos_i cos_o), GGX distribution (Walter et al. 2007), separable Smith
masking, Schlick Fresnel with F0 = the specular albedo. The shading normal is
the surface's. Each sample's parameters are found by least squares over every
(view, light, channel) observation the capture marks valid:

1. start: for each roughness on a grid, (rho_d, F0) enter the model linearly
   (Schlick: F = F0 (1 - c^5') + c^5'), so they are solved in closed form and
   the roughness with the lowest residual is kept (a 1-D search that needs no
   luck);
2. refine: ``optimistix.least_squares`` with Levenberg-Marquardt, ``jax.vmap``
   over samples, in chunks over the sample axis so memory is bounded by the
   chunk; parameters reach their bounds through smooth (sigmoid) transforms.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import lineax as lx
import optimistix as optx
from jaxtyping import Array, Float, Int

import brdf
import stage

from ._maps import MaterialMaps, material_maps

# The fitter's roughness prior, separate from the model's own floor: below
# this a GGX lobe is narrower than any light stage's angular light spacing can
# resolve (about 0.1 rad on Light Stage X), so the data cannot tell values apart.
ALPHA_FIT_MIN = 0.02
ALPHA_FIT_MAX = 1.0
_ALPHA_GRID = (0.03, 0.05, 0.08, 0.12, 0.18, 0.25, 0.35, 0.5, 0.7, 1.0)


class Fit(eqx.Module):
    """The result of a fit: parameter maps (per sample), per-sample RMS residual,
    the Optimistix result code (0 = successful), steps taken and a flag for
    samples without enough valid observations."""

    rho_d: Float[Array, "sample 3"]
    f0: Float[Array, "sample 1"]
    alpha: Float[Array, "sample 1"]
    residual: Float[Array, " sample"]
    result: Int[Array, " sample"]
    steps: Int[Array, " sample"]
    observed: Float[Array, " sample"]

    def material(self) -> brdf.AbstractBRDF:
        """The fitted BRDF (parameters with a leading sample axis)."""
        return brdf.lambert_ggx(self.rho_d, self.f0, self.alpha)

    def maps(self, surface: stage.Surface) -> MaterialMaps:
        """The fit as material maps over ``surface`` (its shading frame, GGX rung)."""
        return material_maps(surface, self.rho_d, self.f0, self.alpha)

    @property
    def failed(self):
        return (self.result != 0) | (self.observed < _MIN_OBSERVATIONS)


# Fewer valid lights than this leave 5 parameters underdetermined in practice.
_MIN_OBSERVATIONS = 8


def _sigmoid_inv(x):
    x = jnp.clip(x, 1e-4, 1 - 1e-4)
    return jnp.log(x) - jnp.log1p(-x)


def _unpack(u):
    rho_d = jax.nn.sigmoid(u[0:3])
    f0 = jax.nn.sigmoid(u[3:4])
    alpha = ALPHA_FIT_MIN + (ALPHA_FIT_MAX - ALPHA_FIT_MIN) * jax.nn.sigmoid(u[4:5])
    return rho_d, f0, alpha


def _pack(rho_d, f0, alpha):
    a = (alpha - ALPHA_FIT_MIN) / (ALPHA_FIT_MAX - ALPHA_FIT_MIN)
    return jnp.concatenate([_sigmoid_inv(rho_d), _sigmoid_inv(f0), _sigmoid_inv(a)], axis=-1)


def _predict(rho_d, f0, alpha, wi, wo, irr):
    """Radiance [N, C] for one sample: wi [N, 3], wo [N, 3], irr [N, C]."""
    m = brdf.lambert_ggx(rho_d[None], f0[None], alpha[None])
    cos_i = jnp.maximum(wi[:, 2:3], 0)
    return m(wi, wo) * cos_i * irr


def _basis(alpha, wi, wo, irr):
    """Columns of the model that are linear in (rho_d, F0) at a fixed roughness."""
    cos_i = jnp.maximum(wi[:, 2:3], 0)
    one = jnp.ones((1, 1), wi.dtype)
    zero = jnp.zeros((1, 1), wi.dtype)
    spec_f1 = brdf.Microfacet(brdf.GGX(alpha * one), brdf.SchlickFresnel(one), "smith")(wi, wo)
    spec_f0 = brdf.Microfacet(brdf.GGX(alpha * one), brdf.SchlickFresnel(zero), "smith")(wi, wo)
    diffuse = cos_i * irr / jnp.pi  # [N, C], multiplies rho_d per channel
    a = (spec_f1 - spec_f0) * cos_i * irr  # multiplies F0
    b = spec_f0 * cos_i * irr  # constant part
    return diffuse, a, b


def _linear_start(obs, w, wi, wo, irr):
    """Closed-form (rho_d, F0) per grid roughness; keep the best. obs, w: [N, C]."""

    def at(alpha):
        d, a, b = _basis(alpha, wi, wo, irr)
        y = obs - b
        # Normal equations of [diag rho_d | F0]: rho_d per channel, F0 shared.
        dd = jnp.sum(w * d * d, 0)
        da = jnp.sum(w * d * a, 0)
        aa = jnp.sum(w * a * a)
        dy = jnp.sum(w * d * y, 0)
        ay = jnp.sum(w * a * y)
        # Schur complement eliminating the 3 diagonal rho_d unknowns.
        dd_s = jnp.maximum(dd, 1e-12)
        s = aa - jnp.sum(da * da / dd_s)
        f0 = jnp.clip(brdf.safe_div(ay - jnp.sum(da * dy / dd_s), s), 1e-3, 0.999)
        rho = jnp.clip((dy - da * f0) / dd_s, 1e-3, 0.999)
        r = obs - (d * rho[None] + a * f0 + b)
        return jnp.sum(w * r * r), rho, f0

    costs, rhos, f0s = jax.vmap(at)(jnp.asarray(_ALPHA_GRID, obs.dtype))
    k = jnp.argmin(costs)
    return rhos[k], f0s[k][None], jnp.asarray(_ALPHA_GRID, obs.dtype)[k][None]


def _residual_fn(obs, w, wi, wo, irr):
    sw = jnp.sqrt(w)

    def residual(u, _):
        return (sw * (_predict(*_unpack(u), wi, wo, irr) - obs)).reshape(-1)

    return residual


@jax.jit
def _start_chunk(obs, w, wi, wo, irr):
    """Closed-form start, packed to the unconstrained parameters [Pc, 5]."""
    return jax.vmap(lambda *a: _pack(*_linear_start(*a)))(obs, w, wi, wo, irr)


@eqx.filter_jit
def _solve_chunk(u0, obs, w, wi, wo, irr, max_steps, rtol, atol):
    """``max_steps`` LM steps from u0 for each sample of the chunk (vmapped)."""

    def one(u0, obs, w, wi, wo, irr):
        residual = _residual_fn(obs, w, wi, wo, irr)
        # Normal equations + Cholesky: the 5x5 system is well conditioned once
        # LM damping is added, and several times cheaper than QR of [N, 5].
        solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol, linear_solver=lx.Normal(lx.Cholesky()))
        sol = optx.least_squares(residual, solver, u0, max_steps=max_steps, throw=False)
        r = residual(sol.value, None)
        rms = jnp.sqrt(jnp.sum(r * r) / jnp.maximum(jnp.sum(w), 1))
        return sol.value, rms, sol.result._value, sol.stats["num_steps"]

    return jax.vmap(one)(u0, obs, w, wi, wo, irr)


# least_squares reports an exhausted step budget as the nonlinear-solver code.
_MAX_STEPS_CODE = int(optx.RESULTS.nonlinear_max_steps_reached._value)


def fit(capture: stage.Capture, surface: stage.Surface, *, chunk: int = 2048, steps_per_round: int = 20,
        rounds: int = 3, rtol: float = 1e-6, atol: float = 1e-7, progress=None) -> Fit:
    """Fit Lambert + GGX (rho_d [3], F0, alpha) per sample to an OLAT capture.

    Observations are every (view, light, channel) with ``capture.mask`` True.
    Samples are solved ``chunk`` at a time (``jax.vmap`` over the chunk), so
    solver memory is bounded by the chunk; each sample gets up to
    ``rounds * steps_per_round`` LM steps, later rounds only for the samples
    still unconverged (compacted). ``progress(n)`` reports finished samples.
    NaN never leaves: a sample with too few observations keeps its closed-form
    start (or grey defaults) and is flagged in ``Fit.failed``.
    """
    V, L, P, C = capture.radiance.shape
    if surface.num_samples != P:
        raise ValueError(f"capture has {P} samples but the surface has {surface.num_samples}")
    if C != 3:
        raise ValueError(f"fit expects RGB radiance (C = 3), got C = {C}")
    if chunk < 1 or rounds < 1 or steps_per_round < 1:
        raise ValueError("chunk, rounds and steps_per_round must be >= 1")
    # Optimistix's LM mixes its damping dtype with JAX's default float, so
    # compute in that (float32 unless jax_enable_x64 is on).
    dt = jnp.result_type(float)
    # One observation count for every chunk (the largest any sample has,
    # rounded up) so the solver compiles once.
    n_valid = np.asarray(jnp.sum(capture.mask, axis=(0, 1)))
    n_keep = int(-(-max(int(n_valid.max()), 1) // 32) * 32)
    data = [_observations(capture, surface, s, min(s + chunk, P), n_keep, dt) for s in range(0, P, chunk)]
    data = [np.concatenate(x) for x in zip(*data)]  # obs, w, wi, wo, irr: [P, n_keep, ...]

    def padded(index):
        """Chunks of ``index``, each padded (repeating its last entry) to ``chunk``."""
        for s in range(0, len(index), chunk):
            idx = index[s:s + chunk]
            if P > chunk:
                idx = np.concatenate([idx, np.full(chunk - len(idx), idx[-1])])
            yield s, idx, min(chunk, len(index) - s)

    every = np.arange(P)
    u = np.zeros((P, 5), dtype=dt)
    for _, idx, n in padded(every):
        u[idx[:n]] = np.asarray(_start_chunk(*(jnp.asarray(x[idx]) for x in data)))[:n]
    rms = np.zeros(P, dt)
    result = np.zeros(P, np.int32)
    steps = np.zeros(P, np.int32)
    # Straggler compaction: every sample gets ``steps_per_round`` LM steps;
    # only those still unconverged go on, packed into full chunks, so a few
    # sharp highlights do not hold a whole vmapped chunk for 60 steps.
    active = every
    for _ in range(rounds):
        for _, idx, n in padded(active):
            out = _solve_chunk(jnp.asarray(u[idx]), *(jnp.asarray(x[idx]) for x in data), steps_per_round, rtol, atol)
            uu, rr, code, k = (np.asarray(x)[:n] for x in out)
            sel = idx[:n]
            u[sel], rms[sel], result[sel], steps[sel] = uu, rr, code, steps[sel] + k
            if progress is not None:
                progress(int(np.sum(code != _MAX_STEPS_CODE)) if active is not every else n)
        active = active[result[active] == _MAX_STEPS_CODE]
        if len(active) == 0:
            break
    rho, f0, alpha = (np.asarray(x) for x in _unpack(jnp.asarray(u).T[:, :, None]))
    rho, f0, alpha = rho[:, :, 0].T, f0[:, :, 0].T, alpha[:, :, 0].T
    nobs = n_valid.astype(np.float32)
    # A sample with no usable data gets grey defaults instead of whatever the solver made of zeros.
    empty = nobs < _MIN_OBSERVATIONS
    rho = np.where(empty[:, None], 0.5, np.nan_to_num(rho, nan=0.5))
    f0 = np.where(empty[:, None], 0.04, np.nan_to_num(f0, nan=0.04))
    alpha = np.where(empty[:, None], 0.3, np.nan_to_num(alpha, nan=0.3))
    rms = np.nan_to_num(rms, nan=np.finfo(np.float32).max, posinf=np.finfo(np.float32).max)
    return Fit(rho_d=jnp.asarray(rho), f0=jnp.asarray(f0), alpha=jnp.asarray(alpha), residual=jnp.asarray(rms),
               result=jnp.asarray(result, jnp.int32), steps=jnp.asarray(steps, jnp.int32),
               observed=jnp.asarray(nobs, jnp.float32))


def _observations(capture, surface, s, e, n_keep, dt):
    """Per-sample observation arrays [e - s, n_keep, ...] for samples s..e:
    radiance, weights (1 valid / 0 padding), wi, wo (local) and irradiance."""
    sub = surface.subset(np.arange(s, e))
    obs_v, w_v, wi_v, wo_v, irr_v = [], [], [], [], []
    for v, cam in enumerate(capture.cameras):
        wi, wo, irr = stage.shading_directions(sub, capture.rig, cam.center)
        obs_v.append(np.swapaxes(np.asarray(capture.radiance[v, :, s:e], np.float32), 0, 1))
        w_v.append(np.swapaxes(np.asarray(capture.mask[v, :, s:e]), 0, 1))
        wi_v.append(np.swapaxes(np.asarray(wi), 0, 1))
        wo_v.append(np.broadcast_to(np.asarray(wo)[:, None], wi_v[-1].shape))
        irr_v.append(np.swapaxes(np.asarray(irr), 0, 1))
    cat = lambda xs: np.concatenate(xs, axis=1)  # noqa: E731  [Pc, V*L, ...]
    obs, wmask, wi, wo, irr = cat(obs_v), cat(w_v), cat(wi_v), cat(wo_v), cat(irr_v)
    # Keep only valid observations (valid first, then padding): typically
    # half of a rig's lights are behind a sample.
    order = np.argsort(~wmask, axis=1, kind="stable")[:, :n_keep]
    take = lambda a: np.take_along_axis(a, order.reshape(order.shape + (1,) * (a.ndim - 2)), axis=1)  # noqa: E731
    obs, wmask, wi, wo, irr = take(obs), take(wmask), take(wi), take(wo), take(irr)
    w = np.broadcast_to(wmask[..., None], obs.shape).astype(dt)
    return obs.astype(dt), w, wi.astype(dt), wo.astype(dt), irr.astype(dt)

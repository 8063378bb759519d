"""Per-texel subsurface: the mean free path and albedo of every texel and
channel, fitted jointly by an Optimistix least-squares solver (Dogleg).

Separability. The diffusion operator sums with the RECEIVING sample's
profile (``skin_bssrdf.DiffusionOperator``): M_p = A_p [c_p(rho_p) E_p +
sum_k R_p(r_pk) a_k E_k], with R_p Christensen & Burley's unit-albedo profile
of shape length d_p = mfp_p / s(A_p) (their eq. 8 "dmfp" fit) and the
transmitted irradiance E fixed (it depends on the normals and the lights, not
on the profile). So texel p's exitance depends on (mfp_p, A_p) alone: the
map-wide least-squares problem is a sum of independent 2-parameter problems
(one per texel and channel), its Gauss-Newton normal matrix block diagonal
with 2 x 2 blocks (``tests/relight/test_fit_sss_texel.py`` checks that the
Jacobian of the map-wide exitance with respect to the mfp map is diagonal).
We therefore ``jax.vmap`` one 2-parameter solve over texels x channels.
Solver: ``optx.Dogleg`` (normal equations + Cholesky), in rounds with
straggler compaction. Measured on the test sphere (490 texels x 3 channels,
48 steps): Levenberg-Marquardt left 41% unconverged (it crawls along the
ln mfp / albedo valley; 99th percentile 280 steps), Gauss-Newton rejected 2%
of its solves, Dogleg converged for 94% (median 13 steps), the rest within
2e-4 in ln mfp of a 400-step solve.

Data terms, reduced exactly. Per light l the views enter only through the
outgoing factor f_v = F_t(cos_o)/pi, so the sum over views of
m_vl (y_vl - A f_v S_l)^2 equals a_l (A S_l - ybar_l)^2 + c_l with
a_l = sum_v m f^2, ybar_l = sum_v m f y / a_l and the constant
c_l = sum_v m y^2 - a_l ybar_l^2: the residual has one entry per light, not per
(view, light), with no approximation. S_l = G_l . w(d) with G the texel's
gathered neighbour irradiance per light [L, K + 1] (self column first) and
w(d) the K + 1 operator weights; G is gathered once per chunk of texels
inside the compiled solve and kept for all steps. The alternative exact
reduction over lights, the Gram matrix G^T diag(a) G [K + 1, K + 1], costs
K^2 per texel and channel instead of L K (smaller only when the neighbourhood
is smaller than the light set) and a least-squares solver needs its Cholesky
factor, K^3: measured on the test sphere (chunk of 128 texels, L = 42, K =
186; scripts/bench_fit_subsurface.py) the gather is 23 MiB in 6-20 ms, the
Gram alone 102 MiB in 86-140 ms; so the gather.
Memory: a chunk holds n x C x L x (K + 1) floats, n chosen so that stays near
``_CHUNK_ELEMENTS``.

Units. Every texel's data (ybar, G, c) is divided by its RMS transmitted
irradiance, as ``relight.fit`` does: the model is linear in the irradiance, so
the parameters do not change and the solver's tolerances and the prior's
noise floor are relative (a capture in other units, rig and radiance x k,
gives the same maps).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx

import skin_bssrdf

from ._devices import RoundsProgress, _chunks_of
from ._result import MAX_STEPS, RESULTS, Fit, result_code
from ._spd import SPDCholesky

# Standard deviation (in ln mfp) of the prior pulling each texel's mean free
# path toward its region's value. Its residual is s (ln mfp - ln mfp_region) /
# PRIOR_SIGMA_LN_MFP with s the texel's current RMS data residual (so the
# prior is a Gaussian of that width in ln mfp relative to a noise-scaled data
# term, in any units): 1.0 is weak (one e-fold, a factor 2.7) where the data
# pin ln mfp to sigma < IDENTIFIED_SIGMA = 0.25, the prior's precision (1) is
# < 1/16 of the data's, so it moves the estimate by < 6% of the gap to the
# region value; where the data do not constrain ln mfp (mfp far below the
# texel spacing, uniform irradiance, unlit) the texel stays at its region
# value instead of wandering to an end of the bracket.
PRIOR_SIGMA_LN_MFP = 1.0
# A texel-channel's mean free path is "identified" when the 1-sigma of ln mfp
# from the data alone is below this (25% relative; Fit.mfp_identified).
IDENTIFIED_SIGMA = Fit.IDENTIFIED_SIGMA
# Fewer valid observations (view x light) per channel than this: not identifiable.
MIN_OBSERVATIONS = 8
# Floats per chunk of gathered irradiance (n x C x L x (K + 1)): ~32 MB in float64.
_CHUNK_ELEMENTS = 1 << 22
# The noise floor of the prior's scale, relative to the RMS observation:
# noise-free synthetic data would otherwise switch the prior off.
_REL_NOISE_FLOOR = 1e-3
_RTOL, _ATOL = 1e-6, 1e-9
# Steps per round of the solver (stragglers go on in later rounds): Dogleg
# converges in a median of 13 steps on the test sphere.
_STEPS_PER_ROUND = 16


class TexelData(eqx.Module):
    """Per texel and light, reduced over views (see the module docstring), in
    the capture's units: a [P, L] = sum_v m f^2, b [P, L, C] = sum_v m f y,
    q [P, L, C] = sum_v m y^2, count [P, L] valid views."""

    a: np.ndarray
    b: np.ndarray
    q: np.ndarray
    count: np.ndarray


def reduce_views(y, valid, f) -> TexelData:
    """The per-light sufficient statistics of y [V, L, P, C] with mask valid
    [V, L, P] and outgoing factor f [V, P] (exact: the model is f_v times a
    function of the light)."""
    m = valid.astype(np.float64)
    mf = m * f[:, None, :]
    a = np.einsum("vlp,vp->pl", mf, f)
    b = np.einsum("vlp,vlpc->plc", mf, y)
    q = np.einsum("vlp,vlpc->plc", m, y * y)
    return TexelData(a=a, b=b, q=q, count=m.sum(0).T)


def _phys(u, lo, hi):
    """(ln mfp, albedo) from the unconstrained u [..., 2]: ln mfp squashed into
    [ln lo, ln hi] by a logistic, the albedo by a logistic into (0, 1)."""
    ln_m = lo + (hi - lo) * jax.nn.sigmoid(u[..., 0])
    return ln_m, jax.nn.sigmoid(u[..., 1])


def unphys(ln_m, A, lo, hi):
    """The inverse of ``_phys`` (numpy), kept off the logistic's flat ends."""
    t = np.clip((ln_m - lo) / (hi - lo), 1e-4, 1 - 1e-4)
    A = np.clip(A, 1e-3, 1 - 1e-3)
    return np.stack([np.log(t / (1 - t)), np.log(A / (1 - A))], -1)


def _exitance(ln_m, A, Gs, Gn, r, rho):
    """S [L]: texel exitance per unit albedo under each light, Burley's profile
    at d = mfp / s(A) through the gathered irradiance (self Gs [L], neighbours
    Gn [L, K] with distances r [K]; padding has Gn = 0)."""
    d = jnp.exp(ln_m) / skin_bssrdf.SCALE_FITS["dmfp"](A)
    prof = skin_bssrdf.Burley(jnp.ones((1,), d.dtype), d[None])
    w_nb = prof.radial(r)[:, 0]  # [K]
    w_self = prof.cumulative(rho)[0]
    return Gs * w_self + Gn @ w_nb


def _gather(idx, Es, nb_index, nb_w, unit):
    """Self [n, C, L] and neighbour [n, C, L, K] irradiance of texels idx,
    the neighbours' already times their area (0 for padding), / unit [n]."""
    Gs = jnp.transpose(Es[:, idx, :], (1, 2, 0)) / unit[:, None, None]
    Gn = Es[:, nb_index[idx], :] * nb_w[idx][None, :, :, None]  # [L, n, K, C]
    Gn = jnp.transpose(Gn, (1, 3, 0, 2)) / unit[:, None, None, None]
    return Gs, Gn


def _stats(ybar, a, c0, cnt, wl):
    """Observations, their energy sum m y^2 and the prior's noise-floor variance for light weights wl."""
    n = jnp.sum(wl * cnt)
    energy = jnp.sum(wl * (a * ybar * ybar + c0))
    floor = (_REL_NOISE_FLOOR ** 2) * energy / jnp.maximum(n, 1.0) + 1e-30
    return n, floor


@eqx.filter_jit
def solve_chunk(idx, Es, nb_index, nb_w, nb_r, rho, unit, a, ybar, c0, cnt, wl, u0, prior, lo, hi, *, max_steps,
                rtol, atol):
    """Optimistix's Dogleg per texel and channel of the chunk idx [n] (vmapped over n x C).

    Es [L, P, C] transmitted irradiance of the chunk's lights; a [n, L],
    ybar / c0 [n, L, C] normalised by unit [n]; cnt [n, L] valid views; wl
    [n, L] light weights (1 fitted, 0 not); u0 [n, C, 2] start; prior [n, C]
    the region's ln mfp. Returns (u [n, C, 2], result code [n, C], steps [n, C])."""
    Gs, Gn = _gather(idx, Es, nb_index, nb_w, unit)
    r = nb_r[idx]
    solver = optx.Dogleg(rtol=rtol, atol=atol, linear_solver=lx.Normal(SPDCholesky()))

    def one(Gs, Gn, r, rho, a, ybar, c0, cnt, wl, u0, prior):
        n, floor = _stats(ybar, a, c0, cnt, wl)
        sw = jnp.sqrt(a * wl)
        const = jnp.sum(wl * c0)

        def res(u, _):
            ln_m, A = _phys(u, lo, hi)
            rd = sw * (A * _exitance(ln_m, A, Gs, Gn, r, rho) - ybar)
            s2 = (jnp.sum(rd * rd) + const) / jnp.maximum(n - 2.0, 1.0) + floor
            rp = jnp.sqrt(s2) * (ln_m - prior) / PRIOR_SIGMA_LN_MFP
            return jnp.concatenate([rd, rp[None]])

        sol = optx.least_squares(res, solver, u0, max_steps=max_steps, throw=False)
        cost0 = jnp.sum(res(u0, None) ** 2)
        cost1 = jnp.sum(res(sol.value, None) ** 2)
        good = jnp.all(jnp.isfinite(sol.value)) & (cost1 <= cost0 * (1 + 1e-9) + 1e-30)
        return (jnp.where(good, sol.value, u0),
                result_code(RESULTS.where(good, RESULTS.promote(sol.result), RESULTS.rejected)),
                sol.stats["num_steps"])

    per_channel = jax.vmap(one, in_axes=(0, 0, None, None, None, 1, 1, None, None, 0, 0))
    return jax.vmap(per_channel)(Gs, Gn, r, rho, a, ybar, c0, cnt, wl, u0, prior)


@eqx.filter_jit
def eval_chunk(idx, Es, nb_index, nb_w, nb_r, rho, unit, a, ybar, c0, cnt, wf, wh, ln_m, A, *, closed_albedo):
    """Scores and uncertainties at (ln mfp, albedo) [n, C] of texels idx.

    ``closed_albedo``: replace A by the least-squares albedo on the lights wf
    (d from the given A: the alternation of the region search). Returns
    (A, SSE on wf, SSE on wh (held-out), observations on wf, on wh, sigma of
    ln mfp, the Fisher information of ln mfp with the albedo marginalised
    (1/sigma^2, 0 where unknown), the held-out squared error per light [n, C, L]);
    SSEs normalised (x unit^2 for capture units)."""
    Gs, Gn = _gather(idx, Es, nb_index, nb_w, unit)
    r = nb_r[idx]

    def one(Gs, Gn, r, rho, a, ybar, c0, cnt, wf, wh, ln_m, A):
        S = _exitance(ln_m, A, Gs, Gn, r, rho)
        if closed_albedo:
            num = jnp.sum(wf * a * S * ybar)
            den = jnp.sum(wf * a * S * S)
            A = jnp.clip(jnp.where(den > 0, num / jnp.where(den > 0, den, 1.0), 0.0), 0.0, 1.0)
        err = a * (A * S - ybar) ** 2 + c0
        sse_f = jnp.sum(wf * err)
        sse_h = jnp.sum(wh * err)
        n_f = jnp.sum(wf * cnt)
        n_h = jnp.sum(wh * cnt)
        sw = jnp.sqrt(a * wf)
        # The data's Jacobian in (ln mfp, A), the prior left out: 1-sigma from s^2 (J^T J)^-1.
        J = jax.jacfwd(lambda t: sw * t[1] * _exitance(t[0], t[1], Gs, Gn, r, rho))(jnp.stack([ln_m, A]))
        jtj = J.T @ J
        s2 = sse_f / jnp.maximum(n_f - 2.0, 1.0)
        det = jtj[0, 0] * jtj[1, 1] - jtj[0, 1] ** 2
        # Singular (e.g. an albedo of 0 or an insensitive d) to 1e-10 relative: not identifiable.
        ok = (det > 1e-10 * jtj[0, 0] * jtj[1, 1]) & (jtj[1, 1] > 0) & (n_f >= MIN_OBSERVATIONS) & (s2 > 0)
        schur = jnp.where(ok, det / jnp.where(ok, jtj[1, 1], 1.0), 0.0)  # J00 - J01^2 / J11
        info = jnp.where(ok, schur / jnp.where(ok, s2, 1.0), 0.0)
        sigma = jnp.where(info > 0, 1.0 / jnp.sqrt(jnp.where(info > 0, info, 1.0)), jnp.inf)
        return A, sse_f, sse_h, n_f, n_h, sigma, info, wh * err

    per_channel = jax.vmap(one, in_axes=(0, 0, None, None, None, 1, 1, None, None, None, 0, 0))
    return jax.vmap(per_channel)(Gs, Gn, r, rho, a, ybar, c0, cnt, wf, wh, ln_m, A)


class Geometry(eqx.Module):
    """The operator's neighbourhoods as the chunk kernels take them: neighbour
    index [P, K], weight = area x valid [P, K] (mm^2), distance [P, K] (mm),
    self radius [P] (mm)."""

    index: jax.Array
    weight: jax.Array
    distance: jax.Array
    rho: jax.Array

    @classmethod
    def of(cls, op: skin_bssrdf.DiffusionOperator, dtype):
        w = jnp.where(op.valid, op.area[op.index], 0.0).astype(dtype)
        return cls(op.index, w, op.distance.astype(dtype), op.self_radius.astype(dtype))


def chunk_size(n_texels: int, L: int, K: int, C: int) -> int:
    """Texels per chunk: n x C x L x (K + 1) near ``_CHUNK_ELEMENTS``, a power of two, no more than the
    power of two holding ``n_texels``. The solvers pass the capture's sample count, so every call of a fit
    (every texel, the subset the ladder keeps, the straggler rounds) has one chunk shape: the vmapped Dogleg
    takes seconds to compile, a padded lane milliseconds."""
    n = max(1, _CHUNK_ELEMENTS // max(C * L * (K + 1), 1))
    n = 1 << (n.bit_length() - 1)
    return int(max(1, min(n, 1 << max(int(n_texels - 1).bit_length(), 0))))


def _normalised(data: TexelData, lights, unit, idx):
    """Per-chunk arrays over the lights: a [n, L], ybar / c0 [n, L, C], count [n, L], normalised by unit."""
    a = data.a[idx][:, lights]
    b = data.b[idx][:, lights]
    q = data.q[idx][:, lights]
    u = unit[idx]
    ok = a > 0
    ybar = np.where(ok[..., None], b / np.where(ok, a, 1.0)[..., None], 0.0)
    c0 = np.maximum(q - a[..., None] * ybar * ybar, 0.0)
    ybar = ybar / u[:, None, None]
    c0 = c0 / (u * u)[:, None, None]
    return a, ybar, c0, data.count[idx][:, lights]


def irradiance_unit(E, data: TexelData):
    """Each texel's RMS transmitted irradiance over the lights that reach a valid view (1 if none)."""
    seen = (data.a > 0).T[..., None]  # [L, P, 1]
    e2 = np.sum(np.where(seen, E * E, 0.0), axis=(0, 2))
    n = E.shape[2] * np.sum(seen[..., 0], axis=0)
    unit = np.sqrt(np.where(n > 0, e2 / np.maximum(n, 1), 1.0))
    return np.where(np.isfinite(unit) & (unit > 0), unit, 1.0)


def fit_texels(E, data: TexelData, geo: Geometry, unit, texels, lights, wl, ln_m0, A0, prior, lo, hi, *, dt,
               max_steps=48, bar=None):
    """The solver for each texel in ``texels`` (all channels) on ``lights``
    (indices) with per-texel weights wl [P, len(lights)]; start (ln_m0, A0)
    and prior [P, C] (ln mfp). Rounds of ``_STEPS_PER_ROUND`` steps, later
    rounds only for the texels still unconverged, packed into full chunks (a
    vmapped solve runs until its slowest lane stops: relight.fit's straggler
    compaction). Returns (ln mfp, A, code, steps), each [len(texels), C]."""
    L, _, C = E.shape
    K = geo.index.shape[1]
    Es = jnp.asarray(E[lights], dt)
    # Sized by the capture's sample count, not len(texels): one program for every call of a fit.
    n = chunk_size(E.shape[1], len(lights), K, C)
    u = unphys(ln_m0[texels], A0[texels], np.log(lo), np.log(hi))
    code = np.zeros((len(texels), C), np.int32)
    steps = np.zeros((len(texels), C), np.int32)
    lo_, hi_ = jnp.asarray(np.log(lo), dt), jnp.asarray(np.log(hi), dt)
    f = lambda x: jnp.asarray(x, dt)  # noqa: E731
    active = np.arange(len(texels))
    per_round = min(_STEPS_PER_ROUND, max_steps)
    count = RoundsProgress(bar)
    for r in range(-(-max_steps // per_round)):  # max_steps rounded up to whole rounds
        for sel, m in _chunks_of(active, n):
            idx = texels[sel]
            a, ybar, c0, cnt = _normalised(data, lights, unit, idx)
            uu, cc, kk = solve_chunk(jnp.asarray(idx), Es, geo.index, geo.weight, geo.distance, geo.rho[idx],
                                     f(unit[idx]), f(a), f(ybar), f(c0), f(cnt), f(wl[idx]), f(u[sel]),
                                     f(prior[idx]), lo_, hi_, max_steps=per_round, rtol=_RTOL, atol=_ATOL)
            s = sel[:m]
            u[s], code[s], steps[s] = np.asarray(uu)[:m], np.asarray(cc)[:m], steps[s] + np.asarray(kk)[:m]
            count.chunk(r == 0, m, int(np.sum(np.all(code[s] != MAX_STEPS, axis=1))))
        active = active[np.any(code[active] == MAX_STEPS, axis=1)]
        if len(active) == 0:
            break
    count.end(len(active))
    ln_m, A = _phys(jnp.asarray(u), lo_, hi_)
    return np.asarray(ln_m, np.float64), np.asarray(A, np.float64), code, steps


def eval_texels(E, data: TexelData, geo: Geometry, unit, texels, lights, wf, wh, ln_m, A, *, dt, closed_albedo):
    """``eval_chunk`` over ``texels``: a dict of A, sse_f, sse_h (capture units^2),
    n_f, n_h, sigma, info, each [len(texels), C], and err_h [len(texels), C, len(lights)]."""
    L, _, C = E.shape
    K = geo.index.shape[1]
    Es = jnp.asarray(E[lights], dt)
    # Sized by the capture's sample count, not len(texels): one program for every call of a fit.
    n = chunk_size(E.shape[1], len(lights), K, C)
    names = ("A", "sse_f", "sse_h", "n_f", "n_h", "sigma", "info", "err_h")
    out = {k: np.zeros((len(texels), C)) for k in names}
    out["err_h"] = np.zeros((len(texels), C, len(lights)))
    pos = np.arange(len(texels))
    for sel, m in _chunks_of(pos, n):
        idx = texels[sel]
        a, ybar, c0, cnt = _normalised(data, lights, unit, idx)
        f = lambda x: jnp.asarray(x, dt)  # noqa: E731
        res = eval_chunk(jnp.asarray(idx), Es, geo.index, geo.weight, geo.distance, geo.rho[idx], f(unit[idx]),
                         f(a), f(ybar), f(c0), f(cnt), f(wf[idx]), f(wh[idx]), f(ln_m[idx]), f(A[idx]),
                         closed_albedo=closed_albedo)
        for k, v in zip(names, res, strict=True):
            out[k][sel[:m]] = np.asarray(v, np.float64)[:m]
    u2 = (unit[texels] ** 2)[:, None]
    out["sse_f"] *= u2
    out["sse_h"] *= u2
    out["err_h"] *= u2[..., None]
    return out

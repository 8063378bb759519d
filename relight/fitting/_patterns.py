"""Per-sample reflectance fitting to pattern captures (``stage.PatternCapture``).

A pattern measurement is a weighted sum of what the sample would show under
each light alone (linearity of light):

    I_k(p, v) = sum_l W[k, l] V_l(p) L_l(u; p, v),      L_l = (rho_d / pi + f_s) cos_i E_l

with W [K, L] the pattern weights in [0, 1], V_l the ray-cast visibility and
L_l the OLAT model of the rung (``relight.fitting._model``, the same kernels
and fitted frame as :func:`relight.fit`). So with W_eff[k, l] = W[k, l] V_l(p),
the pattern residual is W_eff @ (per-light model radiance) - I and its
Jacobian is W_eff @ J_olat (the OLAT model's structured Jacobian, per
channel and view): the normal equations NormalLevenbergMarquardt solves are
(W_eff J)^T (W_eff J). Everything else is the OLAT driver's: the solve and
its accept test, the one-sigma uncertainties from J^T J, the rounds with
straggler compaction, chunks of fixed shape (one compilation per rung), the
flags and the ``Fit`` (``relight.fitting._driver``, ``_result``).

The default start (``start=None``), per sample, from the pattern measurements
alone:

1. normal (``normals=True``): the grey measurement s_k is, for a Lambertian
   sample lit only from its front, linear in b = rho n / pi:
   s_k = b . sum_l W_eff[k, l] E_l w_l (over lights in front of the surface),
   so b is a 3-unknown least-squares solve (for the gradient patterns, the
   ratio Ma et al. 2007 normalise); the surface normal where it fails;
2. albedo: the closed-form Lambert least squares of the measurements on the
   basis sum_l W_eff[k, l] max(cos_i, 0) E_l / pi (the full-on-like solve);
3. for a rung with a lobe, the OLAT start's roughness grid on which
   (rho_d, rho_s) are solved in closed form (the model is linear in them at a
   fixed roughness), here on the pattern-mixed bases
   (``relight.fitting._init.specular_start`` with ``mix``).

A decoder's estimate (``relight.patterns``) can be passed as ``start``
instead.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import stage
from brdf import safe_div, safe_normalize

from ..materials._maps import BLINN_PHONG, GGX_ANISO, MODELS, SUBSURFACE
from . import _init as _fit_init
from . import _model as _fit_model
from ._devices import _chunk_size, _chunks_of, _fit_devices, _placer
from ._driver import LOSSES, run_rounds
from ._ladder import _assemble, finish_block
from ._model import Layout, Params
from ._observations import _obs_bucket
from ._options import FitOptions, as_options
from ._result import Fit, fit_from_arrays, rig_alpha_floor
from ._solvers import resolve_solver, solve_one
from ._spd import spd_solve

__all__ = ["MIN_PATTERN_OBSERVATIONS", "fit_patterns"]

# Fewer valid pattern measurements (views x patterns) than this leave a sample
# underdetermined (Fit.failed): the full-on and three gradient patterns of Ma
# et al. 2007 are the fewest that fix an albedo and a normal.
MIN_PATTERN_OBSERVATIONS = 4
# The per-block working set's budget for the [n, K, L_kept] pattern weights (bytes).
_BLOCK_BYTES = 64 << 20


def _pattern_residual(u, obs, sw, weff, wi, wo, irr, lay: Layout, c):
    """(r [V K C], J [V K C, k], prediction [V, K, C]) of one sample: the
    robust residual robust(sw (W_eff @ L(u) - obs), c) and its Jacobian
    (W_eff @ J_olat, then the robust scaling). obs, sw [V, K, C]; weff [K, Lk];
    wi [Lk, 3], irr [Lk, C] (surface frame, per kept light); wo [V, 3]."""
    V, K, C = obs.shape
    Lk = wi.shape[0]
    k = u.shape[0]
    dt = u.dtype
    n = V * Lk
    wi_n = jnp.broadcast_to(wi[None], (V, Lk, 3)).reshape(n, 3).T
    wo_n = jnp.broadcast_to(wo[:, None], (V, Lk, 3)).reshape(n, 3).T
    irr_n = jnp.broadcast_to(irr[None], (V, Lk, C)).reshape(n, C).T
    # The OLAT model with obs 0, weight 1 and no robust loss: r = the per-light radiance, J its Jacobian.
    _, J_l, pred = _fit_model.residual_and_jacobian(u, jnp.zeros((C, n), dt), jnp.ones((C, n), dt), wi_n, wo_n,
                                                    irr_n, lay, None)
    pred = pred.reshape(C, V, Lk)
    J_l = J_l.reshape(C, V, Lk, k)
    pat = jnp.einsum("kl,cvl->vkc", weff, pred)
    J_p = jnp.einsum("kl,cvlj->vkcj", weff, J_l)
    e = sw * (pat - obs)
    r, dr = jax.jvp(lambda x: _fit_model.robust(x, c), (e,), (jnp.ones_like(e),))
    J = (dr * sw)[..., None] * J_p
    return r.reshape(-1), J.reshape(-1, k), pat


@eqx.filter_jit
def _solve_pattern_chunk(u0, obs, m, weff, wi, wo, irr, *, lay, solver, max_steps, cauchy):
    """``max_steps`` solver steps on each sample of the chunk (vmapped), as the
    OLAT driver's ``_solve_chunk``: (u, rms, code, steps, sigma, 0)."""

    def one(u0, obs, m, weff, wi, wo, irr):
        # Normalised units (radiance per unit irradiance), as the OLAT driver's.
        scale = jnp.sqrt(jnp.sum(m * obs * obs) / jnp.maximum(jnp.sum(m), 1.0))
        c = None if cauchy is None else cauchy * scale + 1e-12
        sw = jnp.sqrt(m)
        u, code, nsteps, sigma, (_, _, pat) = solve_one(
            lambda u: _pattern_residual(u, obs, sw, weff, wi, wo, irr, lay, c), u0, jnp.sum(m), obs.size, lay,
            solver, max_steps)
        raw = pat - obs
        rms = jnp.sqrt(jnp.sum(m * raw * raw) / jnp.maximum(jnp.sum(m), 1.0))
        return u, rms, code, nsteps, sigma, jnp.zeros((), u.dtype)

    return jax.vmap(one)(u0, obs, m, weff, wi, wo, irr)


def pattern_start(obs, m, weff, wi, wo, irr, lay: Layout) -> Params:
    """The default start of one sample from its pattern measurements (module
    docstring, steps 1-3). Arguments as :func:`_pattern_residual`, m the
    measurement weights [V, K, C]."""
    V, K, C = obs.shape
    Lk = wi.shape[0]
    dt = obs.dtype
    z = jnp.asarray([0.0, 0.0, 1.0], dt)
    wi_n = jnp.broadcast_to(wi[None], (V, Lk, 3)).reshape(-1, 3)
    wo_n = jnp.broadcast_to(wo[:, None], (V, Lk, 3)).reshape(-1, 3)
    irr_n = jnp.broadcast_to(irr[None], (V, Lk, C)).reshape(-1, C)

    def mix(x):  # per-(view, light) terms [V Lk, C'] -> pattern measurements [V K, C']
        return jnp.einsum("kl,vlc->vkc", weff, x.reshape(V, Lk, x.shape[-1])).reshape(V * K, x.shape[-1])

    y = obs.reshape(V * K, C)
    w = m.reshape(V * K, C)
    n = z
    if lay.normals:
        front = (wi[:, 2] > 0).astype(dt)
        g = jnp.einsum("kl,l,li->ki", weff, front * jnp.mean(irr, axis=1), wi)  # [K, 3]
        s = jnp.mean(obs, axis=2)  # [V, K]
        mv = jnp.mean(m, axis=2)
        A = jnp.einsum("vk,ki,kj->ij", mv, g, g)
        A = A + 1e-9 * (jnp.trace(A) + 1e-30) * jnp.eye(3, dtype=dt)
        b = spd_solve(A, jnp.einsum("vk,vk,ki->i", mv, s, g))
        cand = safe_normalize(b)
        wo_mean = safe_normalize(jnp.sum(wo * jnp.any(mv > 0, axis=1, keepdims=True).astype(dt), 0) + 1e-12 * z)
        ok = jnp.all(jnp.isfinite(cand)) & (cand[2] > 0.05) & (cand @ wo_mean > 0.05)
        n = jnp.where(ok, cand, z)
    cos_i = jnp.maximum(wi_n @ n, 0.0)[:, None]
    d = mix(cos_i * irr_n / jnp.pi)
    rho = jnp.clip(safe_div(jnp.sum(w * d * y, 0), jnp.sum(w * d * d, 0)), 1e-3, 0.999)
    if lay.model < BLINN_PHONG:
        return Params(rho_d=rho, rho_s=jnp.zeros(1, dt), alpha=jnp.full(2, 0.5, dt), phi=jnp.zeros((), dt), normal=n)
    p = _fit_init.specular_start(y, w, wi_n, wo_n, irr_n, n, lay, mix=mix)
    if lay.model >= GGX_ANISO:
        p["alpha"] = jnp.stack([p["alpha"][0], p["alpha"][0] * 0.999 + 1e-4])
    return p


@jax.jit(static_argnames=("lay",))
def _start_pattern_chunk(obs, m, weff, wi, wo, irr, lay):
    return jax.vmap(lambda *a: _fit_model.pack(pattern_start(*a, lay), lay))(obs, m, weff, wi, wo, irr)


@jax.jit(static_argnames=("lay",))
def _pack_chunk(rho_d, rho_s, alpha, normal, lay):
    def one(rd, rs, a, n):
        p = Params(rho_d=rd, rho_s=rs[None], alpha=jnp.stack([a, a * 0.999 + 1e-4 * (lay.model >= GGX_ANISO)]),
                   phi=jnp.zeros((), rd.dtype), normal=n)
        return _fit_model.pack(p, lay)

    return jax.vmap(one)(rho_d, rho_s, alpha, normal)


def _check_start(start, P: int, normals: bool):
    """``start`` as float64 NumPy arrays (rho_d [P, 3], rho_s [P], alpha [P],
    normal [P, 3] or None) and ``bad`` [P]: samples with a non-finite entry
    (a decoder's NaN for a sample it could not read), which get the default
    start instead. ValueError naming ``start`` and the key for a wrong shape or
    a finite value out of range."""
    if not isinstance(start, dict):
        raise ValueError(f"fit_patterns: start must be None or a dict of per-sample arrays (rho_d [P, 3], rho_s [P], "
                         f"alpha [P], optional normal [P, 3]), got {type(start).__name__}")
    extra = set(start) - {"rho_d", "rho_s", "alpha", "normal"}
    if extra:
        raise ValueError(f"fit_patterns: start has unknown keys {sorted(extra)} (rho_d, rho_s, alpha, normal)")
    out = {}
    for key, shape, lo, hi in (("rho_d", (P, 3), 0.0, 1.0), ("rho_s", (P,), 0.0, 1.0), ("alpha", (P,), 0.0, 1.0),
                               ("normal", (P, 3), -1.0001, 1.0001)):
        if key not in start:
            if key == "normal":
                out[key] = None
                continue
            raise ValueError(f"fit_patterns: start needs {key!r} ({list(shape)})")
        a = np.asarray(start[key], np.float64)
        if key in ("rho_s", "alpha") and a.shape == (P, 1):
            a = a[:, 0]
        if a.shape != shape:
            raise ValueError(f"fit_patterns: start[{key!r}] must have shape {list(shape)}, got {list(a.shape)}")
        fin = np.isfinite(a)
        if np.any(fin & ((a < lo) | (a > hi))):
            raise ValueError(f"fit_patterns: start[{key!r}] must be within [{lo:g}, {hi:g}] (NaN: the default start)")
        out[key] = a
    if not normals:
        out["normal"] = None
    rows = lambda a: ~np.isfinite(a).reshape(P, -1).all(axis=1)  # noqa: E731
    bad = rows(out["rho_d"]) | rows(out["rho_s"]) | rows(out["alpha"])
    if out["normal"] is not None:
        bad |= rows(out["normal"])
        norm = np.linalg.norm(out["normal"], axis=1)
        if not np.all((norm > 0.5) | bad):
            raise ValueError("fit_patterns: start['normal'] must hold unit vectors (world space)")
        out["normal"] = out["normal"] / np.where(bad, 1.0, norm)[:, None]
    for key in ("rho_d", "rho_s", "alpha", "normal"):  # placeholders where the default start takes over
        if out[key] is not None:
            out[key] = np.where(bad.reshape((P,) + (1,) * (out[key].ndim - 1)), 0.5, out[key])
    out["bad"] = bad
    return out


def _start_u0(st, sub, b0: int, b1: int, size: int, lay: Layout, dt) -> np.ndarray:
    """The given physical start of samples b0..b1 (``_check_start``'s arrays) packed to u [n, k]."""
    n = b1 - b0
    normal = np.tile([0.0, 0.0, 1.0], (n, 1))
    if st["normal"] is not None:  # world -> the surface frame
        nw = st["normal"][b0:b1]
        T, B, N = (np.asarray(x, np.float64) for x in (sub.tangent, sub.bitangent, sub.normal))
        normal = np.stack([np.sum(nw * T, 1), np.sum(nw * B, 1), np.sum(nw * N, 1)], axis=1)
    parts = []
    for idx, m in _chunks_of(np.arange(n), size):
        cols = (st["rho_d"][b0:b1], st["rho_s"][b0:b1], st["alpha"][b0:b1], normal)
        parts.append(np.asarray(_pack_chunk(*(jnp.asarray(x[idx], dt) for x in cols), lay))[:m])
    return np.concatenate(parts)


def _visibility_rows(light_visibility, s: int, e: int) -> np.ndarray:
    """bool [e - s, L]: rows s..e of a [P, L] bool mask or ``stage.PackedMask``."""
    if isinstance(light_visibility, stage.PackedMask):
        return np.asarray(stage.PackedMask(light_visibility.bits[s:e], light_visibility.n))
    return np.asarray(light_visibility[s:e], bool)


def _block_arrays(pcapture, light_visibility, surface, W, lit_any, b0, b1, n_keep, dt):
    """The solver's per-sample arrays for samples b0..b1 (normalised, as the
    OLAT driver's ``_normalise``) and the measurement counts and units:
    (obs [n, V, K, C], m [n, V, K, C], weff [n, K, Lk], wi [n, Lk, 3],
    wo [n, V, 3], irr [n, Lk, C]), n_valid [n], unit [n]."""
    sub = surface.take(np.arange(b0, b1))
    rig = pcapture.rig
    wi_world, irr = rig.incident(sub.position)  # [L, n, 3], [L, n, C]
    wi = np.swapaxes(np.asarray(sub.to_local(wi_world), np.float64), 0, 1)
    irr = np.swapaxes(np.asarray(irr, np.float64), 0, 1)
    wo = np.stack([np.asarray(sub.to_local(cam.view_directions(sub.position)), np.float64)
                   for cam in pcapture.cameras], axis=1)  # [n, V, 3]
    keep = _visibility_rows(light_visibility, b0, b1) & lit_any[None]
    order = np.argsort(~keep, axis=1, kind="stable")[:, :n_keep]
    if order.shape[1] < n_keep:
        order = np.concatenate([order, np.repeat(order[:, -1:], n_keep - order.shape[1], axis=1)], axis=1)
    kept = np.take_along_axis(keep, order, axis=1)
    kept[:, keep.shape[1]:] = False
    weff = np.transpose(W[:, order], (1, 0, 2)) * kept[:, None, :]  # [n, K, Lk]
    wi = np.take_along_axis(wi, order[..., None], axis=1)
    irr = np.take_along_axis(irr, order[..., None], axis=1) * kept[..., None]
    rad = np.asarray(pcapture.radiance[:, :, b0:b1], np.float64)  # [V, K, n, C]
    mask = np.asarray(pcapture.mask[:, :, b0:b1], bool) & np.all(np.isfinite(rad), axis=-1)
    obs = np.transpose(np.where(mask[..., None], rad, 0.0), (2, 0, 1, 3))
    m = np.broadcast_to(np.transpose(mask, (2, 0, 1))[..., None], obs.shape).astype(np.float64)
    n_valid = np.sum(mask, axis=(0, 1))
    # Radiance per unit irradiance: divide by each sample's RMS irradiance over its kept lights.
    C = irr.shape[-1]
    cnt = C * np.sum(kept, axis=1)
    unit = np.sqrt(np.where(cnt > 0, np.sum(irr ** 2, axis=(1, 2)) / np.maximum(cnt, 1), 1.0))
    unit = np.where(np.isfinite(unit) & (unit > 0), unit, 1.0)
    obs, irr = obs / unit[:, None, None, None], irr / unit[:, None, None]
    arrays = tuple(x.astype(dt) for x in (obs, m, weff, wi, wo, irr))
    return arrays, sub, n_valid, unit


def _check_args(pcapture, surface, light_visibility, model, loss, cauchy) -> tuple[int, int, int, int]:
    """fit_patterns' argument checks (ValueError / TypeError naming the argument); returns (V, K, P, C)."""
    for name in ("radiance", "valid", "patterns", "rig", "cameras", "mask"):
        if not hasattr(pcapture, name):
            raise TypeError(f"fit_patterns: pcapture must be a stage.PatternCapture, got {type(pcapture).__name__}")
    V, K, P, C = (int(x) for x in pcapture.radiance.shape)
    rig = pcapture.rig
    L = rig.num_lights
    if surface.num_samples != P:
        raise ValueError(f"fit_patterns: the pattern capture has {P} samples but the surface has "
                         f"{surface.num_samples}")
    if C != 3:
        raise ValueError(f"fit_patterns: expects RGB radiance (C = 3), got C = {C}")
    lv_shape = tuple(light_visibility.shape) if hasattr(light_visibility, "shape") else np.shape(light_visibility)
    if lv_shape != (P, L):
        raise ValueError(f"fit_patterns: light_visibility must have shape [P, L] = {(P, L)}, got {lv_shape}")
    if model == "auto" or model not in MODELS or model == MODELS[SUBSURFACE]:
        raise ValueError(f"fit_patterns: model must be one of {MODELS[:SUBSURFACE]}, got {model!r}")
    if loss not in LOSSES:
        raise ValueError(f"fit_patterns: loss must be one of {LOSSES}, got {loss!r}")
    if loss == "cauchy" and not cauchy > 0:
        raise ValueError(f"fit_patterns: the Cauchy scale must be > 0, got {cauchy}")
    return V, K, P, C


def fit_patterns(pcapture, surface: stage.Surface, light_visibility, *, model: str = "ggx", normals: bool = False,
                 start=None, solver="lm", loss: str = "l2", cauchy: float = 0.1, alpha_floor: float | None = None,
                 options: FitOptions | None = None) -> Fit:
    """Fit a reflectance model per sample to a pattern capture, by least
    squares on the pattern measurements themselves (module docstring): the
    prediction of pattern k is sum_l W[k, l] V_l(p) (the rung's one-light
    radiance at light l), against ``pcapture.radiance`` wherever
    ``pcapture.mask`` holds and the measurement is finite (a non-finite
    measurement is left out and not counted, never propagated).

    ``pcapture``: a ``stage.PatternCapture`` (noise-free, or from
    ``stage.sense_patterns``); sample p is sample p of ``surface``;
    ``light_visibility``: bool [P, L] or a ``stage.PackedMask``
    (``stage.light_visibility``: the shadows the pattern frames were lit
    with). ``model``: one rung of ``relight.MODELS`` ("lambert",
    "blinn_phong", "ggx", "ggx_aniso"; the held-out ladder of :func:`fit` is
    not offered: patterns have no lights to hold out). ``normals``: also fit
    the shading normal. ``start``: None (the default start from the
    measurements, module docstring) or a dict of physical per-sample arrays
    {"rho_d": [P, 3], "rho_s": [P], "alpha": [P], optional "normal": [P, 3]
    (world space)}, e.g. a learned decoder's (ValueError naming ``start``
    for a wrong shape or a value out of range; a sample with a non-finite
    entry gets the default start). ``solver``, ``alpha_floor`` as
    :func:`fit`. ``loss``: "l2" (default: each measurement sums many lights,
    so a cast shadow or highlight the model misses is averaged in rather than
    an outlier) or "cauchy" (scale ``cauchy`` x the sample's RMS
    measurement). ``options``: how the fit runs (``FitOptions``, as for
    :func:`fit`; progress phase "fit <rung>"; ``block``: samples whose
    per-sample arrays are held at once, default what keeps the [block, K, L]
    pattern weights within 64 MiB, rounded up to whole chunks).

    Returns a :class:`Fit` as :func:`fit` does: ``residual`` the RMS of the
    pattern residual (the capture's units), ``observed`` the valid pattern
    measurements (views x patterns; ``Fit.failed`` below
    ``MIN_PATTERN_OBSERVATIONS`` = 4), ``uncertainty`` from the pattern
    residual's J^T J (so a parameter the patterns do not constrain is inf,
    ``Fit.unidentified``), ``heldout`` 0.
    """
    options = as_options(options)
    V, K, P, C = _check_args(pcapture, surface, light_visibility, model, loss, cauchy)
    rig = pcapture.rig
    L = rig.num_lights
    stage.check_patterns(np.asarray(pcapture.patterns), L)
    W = np.asarray(pcapture.patterns, np.float64)
    if not isinstance(light_visibility, stage.PackedMask):
        light_visibility = np.asarray(light_visibility, bool)
    solver, solver_name = resolve_solver(solver, options.rtol, options.atol)
    floor = rig_alpha_floor(rig) if alpha_floor is None else float(alpha_floor)
    if not 0 < floor < 1:
        raise ValueError(f"fit_patterns: alpha_floor must be in (0, 1), got {floor}")
    st = None if start is None else _check_start(start, P, normals)
    rung = MODELS.index(model)
    lay = Layout(rung, normals, floor)
    # Optimistix's LM mixes its damping dtype with JAX's default float (as fit does).
    dt = np.dtype(jnp.result_type(float))
    lit_any = W.max(axis=0) > 0
    devs = _fit_devices(options.devices)
    size = -(-_chunk_size(P, options.chunk) // len(devs)) * len(devs)
    # One kept-light count for every chunk (the most any sample has, rounded up): one compilation.
    count_step = 1 << 14
    most = max(int(np.max(np.sum(_visibility_rows(light_visibility, s, min(s + count_step, P)) & lit_any[None],
                                 axis=1))) for s in range(0, P, count_step))
    n_keep = _obs_bucket(most)
    block = max(size, _BLOCK_BYTES // max(K * n_keep * 8, 1)) if options.block is None else options.block
    block = -(-int(block) // size) * size
    opts = dict(size=size, rounds=options.rounds, steps_per_round=options.steps_per_round, solver=solver,
                put=_placer(devs), cauchy=float(cauchy) if loss == "cauchy" else None)
    bar = stage.Phase(options.progress, f"fit {MODELS[rung]}", P)
    fields = None
    for b0 in range(0, P, block):
        b1 = min(b0 + block, P)
        n = b1 - b0
        arrays, sub, n_valid, unit = _block_arrays(pcapture, light_visibility, surface, W, lit_any, b0, b1, n_keep, dt)
        u0 = None if st is None else _start_u0(st, sub, b0, b1, size, lay, dt)
        if u0 is not None and np.any(st["bad"][b0:b1]):
            fallback = st["bad"][b0:b1]
            for idx, m_ in _chunks_of(np.nonzero(fallback)[0], size):
                u0[idx[:m_]] = np.asarray(_start_pattern_chunk(*(jnp.asarray(x[idx]) for x in arrays), lay))[:m_]
        r = run_rounds(arrays, np.arange(n), lay, u0,
                       lambda a: _start_pattern_chunk(*a, lay),
                       lambda u, a: _solve_pattern_chunk(u, *a, lay=lay, solver=solver,
                                                         max_steps=options.steps_per_round, cauchy=opts["cauchy"]),
                       opts, bar)
        choice = np.full(n, rung, np.int32)
        out = _assemble({rung: (np.arange(n), r)}, choice, n, normals, floor, dt, sub, size)
        part = finish_block(out, n_valid, sub, unit, np.zeros(n, dt), choice, dt, MIN_PATTERN_OBSERVATIONS)
        if fields is None:
            fields = {k: np.zeros((P, *v.shape[1:]), v.dtype) for k, v in part.items()}
        for k, v in part.items():
            fields[k][b0:b1] = v
        if options.on_block is not None:
            options.on_block(b0, b1, part)
    return fit_from_arrays(fields, dt, floor, solver_name, min_observed=MIN_PATTERN_OBSERVATIONS)

"""Per-sample reflectance fitting with Optimistix: the driver.

Per sample (texel or pixel) the fitter finds, by least squares over every
(view, light, channel) observation the capture marks valid, the parameters of
one rung of the ladder (``relight.MODELS``): Lambert; + normalised
Blinn-Phong; + isotropic GGX (Walter et al. 2007, Smith masking, Schlick
Fresnel with F0 = the specular albedo: the form Kang et al. 2018 fit);
+ anisotropic GGX with its tangent angle; optionally the shading normal.

1. start (:mod:`relight.fitting._init`): photometric stereo on the lights least
   affected by specular reflection and shadow, then closed-form albedos on a
   roughness grid;
2. refine (:mod:`relight.fitting._solvers`): ``optimistix.least_squares``
   (Levenberg-Marquardt by default; any Optimistix least-squares solver or
   minimiser object, or by name Gauss-Newton, Dogleg, BFGS), ``jax.vmap`` over
   a chunk of samples (:mod:`relight.fitting._devices`), chunks over the
   sample axis so memory is bounded by the chunk, rounds of a few steps with
   only the unconverged samples going on (packed into full chunks: "straggler
   compaction", :func:`run_rounds`); a Cauchy loss so cast shadows and
   interreflections do not drag the fit;
3. ``model="auto"`` (:mod:`relight.fitting._ladder`): every rung is fitted on
   the training lights and scored on held-out lights; each sample gets the
   simplest rung whose held-out error is within noise of the best, then is
   refitted on all lights; a lobe whose peak no light saw and that predicts
   far beyond the data goes one rung down (:mod:`relight.fitting._extrapolation`);
   after every block, a sample left without a lobe because no light sampled
   one takes its neighbours' (:mod:`relight.fitting._neighbours`).

The capture is read a block of samples at a time through
``relight.io.CaptureSource`` (:mod:`relight.fitting._sources`) and packed into
observations (:mod:`relight.fitting._observations`); the result is a ``Fit``
(:mod:`relight.fitting._result`). How the fit runs (chunk, block, rounds,
devices, callbacks, tolerances) is a ``FitOptions``. Subsurface (mean free
path) is fitted afterwards, across samples, by :func:`relight.fit_subsurface`.
"""

from __future__ import annotations

import dataclasses
import warnings

import jax
import jax.numpy as jnp
import numpy as np

import stage

from ..io import CaptureSource, valid_counts
from ..materials._maps import MODELS
from . import _model as _fit_model
from ._devices import RoundsProgress, _chunk_size, _chunks_of, _fit_devices, _placer
from ._extrapolation import extrapolated_highlights
from ._ladder import _assemble, _rungs, choose_rungs, finish_block, heldout_weights, specular_cosines
from ._model import Layout
from ._neighbours import lobes_from_neighbours
from ._observations import _normalise, _obs_bucket, _observations_of
from ._options import FitOptions, as_options
from ._result import FIELDS, MAX_STEPS, MIN_OBSERVATIONS, Fit, fit_from_arrays, rig_alpha_floor
from ._shadows import shadowed
from ._solvers import _solve_chunk, _start_chunk, resolve_solver
from ._sources import open_source, read_block

LOSSES = ("cauchy", "l2")
# relight.fit's model and loss when not told: chosen on the outside-data suite (docs/fit.md, "Defaults").
DEFAULT_MODEL = "auto"
DEFAULT_LOSS = "l2"
# fit's samples per block when FitOptions.block is None.
DEFAULT_BLOCK = 4096


@dataclasses.dataclass
class _Plan:
    """What a fit sets up before its first block (:func:`_plan`): shared by :func:`fit` and
    :func:`relight.fitting.fit_parts`, so both fit every block with the same programs."""

    source: CaptureSource
    rig: stage.Rig
    cameras: tuple
    P: int
    rungs: tuple[int, ...]
    normals: bool
    floor: float
    holdout: int
    solver_name: str
    dt: np.dtype
    block: int
    chunk: int
    opts: dict
    devices: int
    n_valid: np.ndarray | None = None
    n_keep: int | None = None
    shadow_ratio: float | None = None
    neighbour_lobes: bool = False

    def set_counts(self, n_valid) -> None:
        """Set the valid observations per sample [P] and the packed observation count they give (the
        most any sample has, rounded up to a bucket of :func:`_obs_bucket`): one observation count
        for every chunk of every block, so the solver compiles once."""
        self.n_valid = np.asarray(n_valid)
        self.n_keep = _obs_bucket(int(np.max(self.n_valid)))


def _plan(capture, surface: stage.Surface, *, model, normals, solver, loss, cauchy, alpha_floor, holdout,
          options: FitOptions, shadow_ratio: float | None = None, neighbour_lobes: bool = True,
          block: int | None = None, count: bool = True, where: str = "fit") -> _Plan:
    """Check ``fit``'s arguments and set the fit up (``block``: overrides ``options.block``;
    ``count=False``: the caller counts the valid observations, :meth:`_Plan.set_counts`).
    ValueError / TypeError naming the argument."""
    source, rig, cameras = open_source(capture, where)
    V, L, P, C = (int(s) for s in source.shape)
    if surface.num_samples != P:
        raise ValueError(f"{where}: capture has {P} samples but the surface has {surface.num_samples}")
    if C != 3:
        raise ValueError(f"{where}: expects RGB radiance (C = 3), got C = {C}")
    if loss not in LOSSES:
        raise ValueError(f"{where}: loss must be one of {LOSSES}, got {loss!r}")
    if loss == "cauchy" and not cauchy > 0:
        raise ValueError(f"{where}: the Cauchy scale must be > 0, got {cauchy}")
    if shadow_ratio is not None and not 0 < shadow_ratio < 1:
        raise ValueError(f"{where}: shadow_ratio must be None or in (0, 1), got {shadow_ratio!r}")
    if model == "auto" and holdout < 2:
        raise ValueError(f"{where}: holdout must be >= 2 (every holdout-th light is held out), got {holdout}")
    solver, solver_name = resolve_solver(solver, options.rtol, options.atol)
    rungs = _rungs(model)
    floor = rig_alpha_floor(rig) if alpha_floor is None else float(alpha_floor)
    if not 0 < floor < 1:
        raise ValueError(f"{where}: alpha_floor must be in (0, 1), got {floor}")
    devs = _fit_devices(options.devices)
    block = block if block is not None else DEFAULT_BLOCK if options.block is None else options.block
    if isinstance(block, bool) or not isinstance(block, (int, np.integer)) or block < 1:
        raise ValueError(f"{where}: block must be an int >= 1 (samples per block), got {block!r}")
    block = int(block)
    # Optimistix's LM mixes its damping dtype with JAX's default float, so
    # compute in that (float32 unless jax_enable_x64 is on).
    dt = np.dtype(jnp.result_type(float))
    # One padded chunk shape for the whole fit (P, not the block, sets it; a multiple of the devices)
    # and one observation count (set_counts: a pass over the mask only), so every block and every
    # process compiles the same programs.
    size = -(-_chunk_size(P, options.chunk) // len(devs)) * len(devs)
    opts = dict(size=size, rounds=options.rounds, steps_per_round=options.steps_per_round, solver=solver,
                put=_placer(devs), cauchy=float(cauchy) if loss == "cauchy" else None)
    plan = _Plan(source, rig, cameras, P, rungs, bool(normals), floor, int(holdout), solver_name, dt, block,
                 int(options.chunk), opts, len(devs),
                 shadow_ratio=None if shadow_ratio is None else float(shadow_ratio),
                 neighbour_lobes=bool(neighbour_lobes) and len(rungs) > 1)
    if count:
        plan.set_counts(valid_counts(source, block))
    return plan


def fit(capture, surface: stage.Surface, *, model: str = DEFAULT_MODEL, normals: bool = False, solver="lm",
        loss: str = DEFAULT_LOSS, cauchy: float = 0.1, alpha_floor: float | None = None, holdout: int = 5,
        shadow_ratio: float | None = None, neighbour_lobes: bool = True,
        options: FitOptions | None = None) -> Fit:
    """Fit a reflectance model per sample to an OLAT capture.

    NaN never leaves: a sample with too few observations gets grey defaults, and one whose solve
    fails keeps its start; both are flagged in ``Fit.failed``. Memory and devices
    (``options``; docs/fit.md, "Memory and devices"): samples are read, turned into observations,
    fitted and freed a block at a time, so the working set is set by ``options.block``, not by P;
    the result is a few floats per sample, and any block gives the same fit.

    Args:
        capture: a ``stage.Capture``, or a ``relight.io.CaptureSource`` read a block of samples at
            a time, never whole (``relight.io.open_capture_store``, ``relight.io.open_capture``, a
            ``relight.io.SampleSubset``). Sample p of the capture is sample p of ``surface``.
        surface: the samples' ``stage.Surface``.
        model: "auto" (default) or a rung of ``relight.MODELS`` ("lambert", "blinn_phong", "ggx",
            "ggx_aniso"). "auto" is the ladder: every rung is fitted on all but every ``holdout``-th of
            each sample's valid observations ranked from its mirror direction outward, scored on those,
            and each sample keeps the simplest rung whose prediction error (the held-out and the
            parameter-corrected training mean squared errors, pooled) is within two standard errors of
            the noise of the best (``_ladder.choose_rungs``); then it is refitted on every light, and
            goes one rung down while its lobe's peak lies where no light saw it and predicts more than
            4x its brightest observation (docs/fit.md, "How", item 8). The defaults, "auto" with
            ``loss="l2"``, are the suite's choice (docs/fit.md, "Defaults").
        normals: also fit the shading normal (photometric-stereo start).
        solver: an Optimistix least-squares solver or minimiser object
            (``optx.LevenbergMarquardt(rtol, atol)``, ``optx.GaussNewton``, ``optx.Dogleg``,
            ``optx.BFGS``, ...), used as it is; or one of the names ``SOLVERS``: "lm"
            (Levenberg-Marquardt, default), "optx-lm", "gn" (Gauss-Newton), "dogleg", "bfgs", which
            stand for those solvers with tolerances ``options.rtol`` / ``options.atol`` (default
            1e-5 / 1e-6) and, but for "bfgs", the normal-equations Cholesky linear solver.
            ``Fit.solver`` records the name. An Optimistix solver of your own that takes a linear
            solver should get ``lineax.Normal(relight.fitting.SPDCholesky())`` on the CPU, not
            ``lineax.Cholesky()`` (batched LAPACK can hang there: docs/fit.md, "Findings", item 8).
            The solver sees each sample's radiance and irradiance
            divided by its RMS irradiance (docs/fit.md, "Units and scale"), so ``atol`` applies to
            residuals in radiance per unit irradiance, whatever the capture's units: the fit is
            invariant under a change of units (rig intensities and radiance x k).
        loss: "l2" (default) or "cauchy" (scale ``cauchy`` x the sample's RMS radiance; robust to
            unmasked shadows, but it also down-weights real highlights).
        cauchy: the Cauchy loss's relative scale.
        alpha_floor: smallest roughness; default :func:`rig_alpha_floor`.
        holdout: for ``model="auto"``: every ``holdout``-th of each sample's observations, ranked
            from the mirror direction, is held out.
        shadow_ratio: None (default) or a fraction in (0, 1) (``relight.fitting.SHADOW_RATIO`` = 0.5):
            after the fit, every valid observation darker than this fraction of its prediction is taken
            for a cast shadow the model does not have, censored (weight 0), and each sample is refitted
            from its first fit. A sample left with fewer than ``MIN_OBSERVATIONS`` keeps them all.
            ``Fit.rms`` is then over the kept observations (docs/fit.md, "How", item 4).
        neighbour_lobes: for ``model="auto"``: a sample left on Lambert whose lights never sampled a lobe
            (no valid half vector within the lobe's half maximum) takes the median microfacet lobe of
            its nearest fitted samples, where a quarter of them have one, if its own observations are
            predicted at least as well (:mod:`relight.fitting._neighbours`); its F0 and roughness sigmas are inf
            (a prior, not a measurement). False: every sample from its own data alone.
        options: how the fit runs (:class:`FitOptions`: chunk, block, rounds, steps, tolerances,
            devices, progress, on_block); None = the defaults.

    Returns:
        A ``Fit`` over the P samples.

    Raises ValueError / TypeError naming the argument.
    """
    options = as_options(options)
    plan = _plan(capture, surface, model=model, normals=normals, solver=solver, loss=loss, cauchy=cauchy,
                 alpha_floor=alpha_floor, holdout=holdout, shadow_ratio=shadow_ratio,
                 neighbour_lobes=neighbour_lobes, options=options)
    P = plan.P
    kinds = {"f": plan.dt, "i": np.int32, "o": np.float32}
    out = {k: np.zeros((P, *shape), kinds[c]) for k, (shape, c) in FIELDS.items()}
    phases = _Phases(options.progress)
    chosen = dict.fromkeys(plan.rungs, 0)
    for b0 in range(0, P, plan.block):
        b1 = min(b0 + plan.block, P)
        part = _fit_block(plan, surface, b0, b1, phases, chosen)
        for k, v in part.items():
            out[k][b0:b1] = v
        if options.on_block is not None:
            options.on_block(b0, b1, part)
    # A refit phase whose rung the last block did not use learns its total only now.
    for k in plan.rungs if len(plan.rungs) > 1 else ():
        phases.finish(f"fit {MODELS[k]}", chosen[k])
    _warn_albedo_at_bound(out["rho_d"], plan.n_valid >= MIN_OBSERVATIONS)
    fitted = fit_from_arrays(out, plan.dt, plan.floor, plan.solver_name)
    if plan.neighbour_lobes:
        fitted = lobes_from_neighbours(fitted, plan, surface, options.progress)
    return fitted


# A diffuse albedo this close to 1, the model's bound (energy conservation), is pressed against it; on more than
# ALBEDO_BOUND_FRACTION of the fitted samples that is the units, not the material.
ALBEDO_BOUND = 0.98
ALBEDO_BOUND_FRACTION = 0.05


def _warn_albedo_at_bound(rho_d: np.ndarray, fitted: np.ndarray) -> None:
    """Warn when many fitted samples' diffuse albedo reaches the model's bound of 1: a diffuse surface
    reflects at most what it receives, so the radiance is too large for the lights' stated intensities
    (uncalibrated strobes read with intensity 1, sensor counts with no gain): the fit clips, it does not fit."""
    n = int(np.sum(fitted))
    if n == 0:
        return
    frac = float(np.sum(np.any(rho_d[fitted] >= ALBEDO_BOUND, axis=-1))) / n
    if frac > ALBEDO_BOUND_FRACTION:
        warnings.warn(f"fit: {frac:.0%} of the {n} fitted samples reach diffuse albedo 1, the model's bound: the "
                      f"radiance is larger than the lights' intensities allow. Likely wrong units (uncalibrated "
                      f"lights read with intensity 1, sensor counts with no gain): scale the rig's intensities "
                      f"or the radiance (docs/fit.md, 'Units and scale').", stacklevel=3)


class _Phases:
    """One progress counter per phase name for the whole fit, made at first use, so a phase
    spans every block (``stage.Phase``; its total may be set later, when known)."""

    def __init__(self, progress):
        self.progress, self.bars = progress, {}

    def __call__(self, name: str, total: int | None) -> stage.Phase:
        bar = self.bars.get(name)
        if bar is None:
            bar = self.bars[name] = stage.Phase(self.progress, name, total)
        else:
            bar.total = total
        return bar

    def finish(self, name: str, total: int) -> None:
        """Report ``name``'s total if the blocks that ran it did not know it yet."""
        bar = self.bars.get(name)
        if bar is not None and bar.total is None:
            bar.total = total
            bar.advance(0)


def _fit_block(plan: _Plan, surface: stage.Surface, b0: int, b1: int, phases: _Phases, chosen: dict) -> dict:
    """Every rung (and the ladder's choice) for samples b0..b1: the Fit's per-sample fields as NumPy
    arrays [b1 - b0, ...] (``FIELDS``). The block's observations live only in here. ``chosen``
    counts, per rung, the samples that chose it so far (the refit phases' totals)."""
    n, dt, chunk = b1 - b0, plan.dt, plan.chunk
    last = b1 == plan.P
    rad, mask = read_block(plan.source, b0, b1)
    # Every chunk padded to ``chunk`` samples (repeating its last): the shading geometry's programs
    # compile for one shape, whatever the block or capture size.
    parts = []
    for s in range(0, n, chunk):
        idx, m = next(_chunks_of(np.arange(s, min(s + chunk, n)), chunk))
        part = _observations_of(rad[:, :, idx], mask[:, :, idx], plan.rig, plan.cameras, surface.take(b0 + idx),
                                plan.n_keep, dt)
        parts.append(tuple(x[:m] for x in part))
    del rad, mask
    obs, w, wi, wo, irr, _light = (np.concatenate(x) for x in zip(*parts, strict=True))
    del parts
    # The solver sees radiance per unit irradiance (docs/fit.md, "Units and scale").
    obs, irr, unit = _normalise(obs, w, irr)
    data = (obs, w, wi, wo, irr)
    every = np.arange(n)
    zero = np.zeros_like(w)
    block_surface = surface.take(np.arange(b0, b1))
    lay = lambda k: Layout(k, plan.normals, plan.floor)  # noqa: E731
    opts, rungs, P = plan.opts, plan.rungs, surface.num_samples

    if len(rungs) == 1:
        k = rungs[0]
        choice = np.full(n, k, np.int32)
        fits = {k: (every, _fit_rung(data, w, zero, every, lay(k), None, opts, phases(f"fit {MODELS[k]}", P)))}
        heldout = np.zeros(n, dt)
    else:
        hmask = heldout_weights(w, specular_cosines(data, plan.normals, opts["size"]), plan.holdout)
        train = w - hmask
        trial = {k: _fit_rung(data, train, hmask, every, lay(k), None, opts,
                              phases(f"fit {MODELS[k]} (held out)", P)) for k in rungs}
        choice, heldout = choose_rungs(trial, rungs, hmask, np.sum(train[..., 0] > 0, axis=1), dt, plan.normals)
        fits = {}
        for k in rungs:
            sel = np.nonzero(choice == k)[0]
            chosen[k] += len(sel)
            if len(sel):
                bar = phases(f"fit {MODELS[k]}", chosen[k] if last else None)
                fits[k] = (sel, _fit_rung(data, w, zero, sel, lay(k), trial[k]["u"][sel], opts, bar))
        # A rung whose highlight the lights never saw is not kept: one rung down, refitted.
        for k in rungs[:0:-1]:
            if k not in fits:
                continue
            sel, r = fits[k]
            bad = extrapolated_highlights(r["u"], lay(k), data, sel, opts["size"])
            if not bad.any():
                continue
            fits[k] = (sel[~bad], {f: v[~bad] for f, v in r.items()})
            down = rungs[rungs.index(k) - 1]
            moved = sel[bad]
            choice[moved] = down
            heldout[moved] = np.sqrt(trial[down]["hmse"][moved]).astype(dt)
            chosen[down] += len(moved)
            bar = phases(f"fit {MODELS[down]}", chosen[down] if last else None)
            new = _fit_rung(data, w, zero, moved, lay(down), trial[down]["u"][moved], opts, bar)
            if down in fits:
                old_sel, old = fits[down]
                new = {f: np.concatenate([old[f], new[f]]) for f in old}
                moved = np.concatenate([old_sel, moved])
            fits[down] = (moved, new)
        fits = {k: v for k, v in fits.items() if len(v[0])}
    if plan.shadow_ratio is not None:
        fits = _refit_without_shadows(plan, data, fits, lay, phases)
    out = _assemble(fits, choice, n, plan.normals, plan.floor, dt, block_surface, opts["size"])
    return finish_block(out, plan.n_valid[b0:b1], block_surface, unit, heldout, choice, dt, MIN_OBSERVATIONS)


def _refit_without_shadows(plan: _Plan, data, fits: dict, lay, phases: _Phases) -> dict:
    """Each rung's samples with observations darker than ``plan.shadow_ratio`` x their prediction
    (:func:`relight.fitting._shadows.shadowed`: cast shadows only darken, and a shadowed observation
    reads the indirect light only) refitted without them, from a new start on the kept observations:
    the first start (photometric stereo) saw the shadows too. A sample with none keeps its fit, which
    the refit would repeat exactly (same start, same data)."""
    w, zero, out = data[1], np.zeros_like(data[1]), {}
    for k, (sel, r) in fits.items():
        cut = shadowed(r["u"], lay(k), data, sel, plan.shadow_ratio, plan.opts["size"], MIN_OBSERVATIONS)
        hit = np.any(cut, axis=1)
        if not hit.any():
            out[k] = (sel, r)
            continue
        w2 = w.copy()
        w2[sel[hit]] = np.where(cut[hit][..., None], 0, w[sel[hit]])
        bar = phases("fit (shadows censored)", None)  # how many samples have shadows is known only now
        new = _fit_rung(data, w2, zero, sel[hit], lay(k), None, plan.opts, bar)
        merged = {f: v.copy() for f, v in r.items()}
        for f, v in new.items():
            merged[f][hit] = v
        out[k] = (sel, merged)
    return out


def _fit_rung(data, w, h, index, lay, u0, opts, bar):
    """Fit one rung to the samples ``index`` (of the block ``data``); returns
    per-sample arrays over ``index`` (:func:`run_rounds`)."""
    obs, _, wi, wo, irr = data
    return run_rounds(
        (obs, w, h, wi, wo, irr), index, lay, u0,
        lambda a: _start_chunk(a[0], a[1], a[3], a[4], a[5], lay),
        lambda u, a: _solve_chunk(u, *a, lay=lay, solver=opts["solver"], max_steps=opts["steps_per_round"],
                                  cauchy=opts["cauchy"]),
        opts, bar)


def run_rounds(arrays, index, lay, u0, start, solve, opts, bar):
    """The rounds of a rung's solve over the samples ``index`` of ``arrays``
    (per-sample NumPy arrays, sample axis first), shared by :func:`fit` and
    :func:`relight.fitting.fit_patterns`: ``opts["size"]`` samples per call
    (padded: one compilation), each round only the samples still at
    ``max_steps`` (straggler compaction), ``opts["rounds"]`` rounds.
    ``start(chunk arrays) -> u [size, k]`` when ``u0`` is None;
    ``solve(u, chunk arrays) -> (u, rms, code, steps, sigma, held-out MSE)``.
    Progress on ``bar`` (a ``stage.Phase``): :class:`RoundsProgress`. Every
    chunk goes to the devices through ``opts["put"]`` (:func:`_placer`)."""
    dtype = arrays[0].dtype
    chunk = opts["size"]
    put = opts["put"]
    n_all = len(index)
    local = np.arange(n_all)
    take = lambda idx: tuple(put(x[index[idx]]) for x in arrays)  # noqa: E731
    if u0 is None:
        u = np.zeros((n_all, lay.size), dtype)
        for idx, n in _chunks_of(local, chunk):
            u[idx[:n]] = np.asarray(start(take(idx)))[:n]
    else:
        u = np.array(u0, dtype)
    rms = np.zeros(n_all, dtype)
    hmse = np.zeros(n_all, dtype)
    code = np.zeros(n_all, np.int32)
    steps = np.zeros(n_all, np.int32)
    # The length of the reported parameter vector, from shapes alone (jax.eval_shape: nothing dispatched or
    # compiled, as op-by-op evaluation of a zero vector would be for each new layout).
    n_phys = jax.eval_shape(lambda v: _fit_model.physical_vector(_fit_model.unpack(v, lay), lay),
                            jax.ShapeDtypeStruct((lay.size,), jnp.result_type(float))).shape[0]
    sigma = np.zeros((n_all, n_phys), dtype)
    active = local
    count = RoundsProgress(bar)
    for r in range(opts["rounds"]):
        for idx, n in _chunks_of(active, chunk):
            out = solve(put(u[idx]), take(idx))
            uu, rr, cc, kk, ss, hh = (np.asarray(x)[:n] for x in out)
            sel = idx[:n]
            u[sel], rms[sel], code[sel], steps[sel], sigma[sel], hmse[sel] = uu, rr, cc, steps[sel] + kk, ss, hh
            count.chunk(r == 0, n, int(np.sum(cc != MAX_STEPS)))
        active = active[code[active] == MAX_STEPS]
        if len(active) == 0:
            break
    count.end(len(active))
    return dict(u=u, rms=rms, hmse=hmse, code=code, steps=steps, sigma=sigma)

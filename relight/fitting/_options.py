"""How a fit runs (``FitOptions``), apart from what it fits (``relight.fit``'s own keywords)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import jax
import numpy as np

import stage


def _positive_int(name: str, value, allow_none: bool = False) -> None:
    if allow_none and value is None:
        return
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"FitOptions: {name} must be an int >= 1, got {value!r}")


@dataclasses.dataclass(frozen=True, kw_only=True)
class FitOptions:
    """How :func:`relight.fit` and :func:`relight.fitting.fit_patterns` run: memory, devices,
    solver schedule and tolerances, callbacks. None of them changes what is fitted; ``block`` and
    ``devices`` do not change the numbers either, ``chunk``, ``rounds``, ``steps_per_round``,
    ``rtol`` and ``atol`` change them within the solver's tolerance.

    **Attributes:**

    - ``chunk``: samples per solver call (default 64). The solve is ``jax.vmap`` ped over a chunk and
      runs until its slowest sample stops, so small chunks waste fewer steps; every call has the
      same shape, so each rung compiles once per fit. Solver memory is bounded by the chunk.
    - ``block``: samples read, turned into observations, fitted and freed at a time (every rung, the
      ladder's choice included); sets the working set (about 40 KiB per sample of a block), not the
      capture's size. Any block gives the same fit; ``block >= P`` is one block. None: the fitter's
      default (:func:`relight.fit`: 4096; ``fit_patterns``: what keeps the block's pattern weights
      within 64 MiB).
    - ``rounds``, ``steps_per_round``: each sample gets up to ``rounds * steps_per_round`` solver
      steps (defaults 12 and 20), later rounds only for the samples still unconverged, packed into
      full chunks ("straggler compaction"), so a budget that most samples never reach costs little.
      It is large enough that running out of it (``Fit.failed``) marks a sample the solver cannot
      fit, not one it had no time for (docs/fit.md, "The step budget").
    - ``rtol``, ``atol``: the tolerances of a solver given by name (default 1e-5 / 1e-6, on
      residuals in radiance per unit irradiance: docs/fit.md, "Units and scale"); None with a
      solver object (it carries its own).
    - ``devices``: None = every local device (``jax.local_devices()``), an int n = the first n, or a
      sequence of devices; with several, each chunk (rounded up to a multiple of their number) has
      its sample axis split over them (``NamedSharding`` on a 1-D ``Mesh`` named "samples").
    - ``progress``: ``progress(phase, done, total)`` (``stage.Progress``), finished samples per
      phase (``relight.fit``: "fit <rung>", and for ``model="auto"`` "fit <rung> (held out)").
    - ``on_block``: ``on_block(start, stop, arrays)``, called after each block with ``arrays`` a
      dict of NumPy arrays over samples start..stop: the Fit's per-sample fields as they will be in
      the result (rho_d, rho_s, alpha, normal, tangent, model, residual, heldout, result, steps,
      observed, uncertainty), to write results as they are made.

    Raises ValueError / TypeError naming the field on a bad value.
    """

    chunk: int = 64
    block: int | None = None
    rounds: int = 12
    steps_per_round: int = 20
    rtol: float | None = None
    atol: float | None = None
    devices: int | Sequence[jax.Device] | None = None
    progress: stage.Progress | None = None
    on_block: Callable[[int, int, dict[str, Any]], None] | None = None

    def __post_init__(self):
        for name in ("chunk", "rounds", "steps_per_round"):
            _positive_int(name, getattr(self, name))
        _positive_int("block", self.block, allow_none=True)
        for name in ("rtol", "atol"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, (int, float, np.floating)) and v >= 0):
                raise ValueError(f"FitOptions: {name} must be None or a number >= 0, got {v!r}")
        if self.progress is not None and not callable(self.progress):
            raise TypeError(f"FitOptions: progress must be a callable progress(phase, done, total) or None, "
                            f"got {self.progress!r}")
        if self.on_block is not None and not callable(self.on_block):
            raise TypeError(f"FitOptions: on_block must be a callable on_block(start, stop, arrays) or None, "
                            f"got {self.on_block!r}")


def as_options(options: FitOptions | None) -> FitOptions:
    """``options``, or the defaults for None; TypeError for anything else."""
    if options is None:
        return FitOptions()
    if not isinstance(options, FitOptions):
        raise TypeError(f"options must be a relight.fitting.FitOptions or None, got {type(options).__name__}")
    return options

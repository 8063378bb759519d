"""Where and in what shapes a fit runs: its devices, the placement of a chunk on them, and the
fixed-shape chunks of samples (one compilation per rung whatever the capture's size).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def _fit_devices(devices) -> list:
    """The devices a fit runs on: None = every local device (``jax.local_devices()``),
    an int n = the first n of them, or a sequence of devices. ValueError naming ``devices``."""
    local = jax.local_devices()
    if devices is None:
        return list(local)
    if isinstance(devices, (int, np.integer)) and not isinstance(devices, bool):
        if not 1 <= int(devices) <= len(local):
            raise ValueError(f"fit: devices must be between 1 and the {len(local)} local device(s), got {devices}")
        return list(local[:int(devices)])
    try:
        devs = list(devices)
    except TypeError:
        raise ValueError(f"fit: devices must be None, an int or a sequence of jax devices, got {devices!r}") from None
    if not devs or not all(isinstance(d, jax.Device) for d in devs) or len(set(devs)) != len(devs):
        raise ValueError(f"fit: devices must be a non-empty sequence of distinct jax devices, got {devices!r}")
    return devs


def _placer(devs):
    """``put(x)``: a NumPy chunk [n, ...] as a jax array on ``devs``. One device: that device (the
    default device's is today's ``jnp.asarray``). Several: the sample axis split over a 1-D
    ``Mesh(devs, ("samples",))`` (``NamedSharding(mesh, PartitionSpec("samples"))``, the rest
    replicated), so the jitted vmapped solve runs data-parallel: no sample talks to another, and the
    partitioner only adds an all-reduce for the batched while loop's "any sample still running"."""
    if len(devs) == 1:
        if devs[0] == jax.devices()[0]:
            return jnp.asarray
        return lambda x: jax.device_put(x, devs[0])
    mesh = jax.sharding.Mesh(np.asarray(devs, dtype=object), ("samples",))
    sharding = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("samples"))
    return lambda x: jax.device_put(x, sharding)


# Solver calls are never narrower than this many samples (unless ``chunk`` is): below it a padded lane
# costs microseconds a step, while each other width would compile every rung's solver again.
_MIN_CHUNK = 64


def _chunk_size(P: int, chunk: int) -> int:
    """Samples per solver call: ``chunk``, or for fewer samples the next power of two, at least
    ``_MIN_CHUNK`` (so the small fits of one program share its compilations) and never more than ``chunk``."""
    return chunk if P >= chunk else min(chunk, max(_MIN_CHUNK, 1 << int(P - 1).bit_length()))


def _chunks_of(index, size):
    """Chunks of ``index``, each padded (repeating its last entry) to ``size``:
    one shape for every call of a fit (straggler rounds and ladder subsets
    included), so the solver compiles once per rung."""
    for s in range(0, len(index), size):
        idx = index[s:s + size]
        n = len(idx)
        if n < size:
            idx = np.concatenate([idx, np.full(size - n, idx[-1])])
        yield idx, n


class RoundsProgress:
    """The progress of a solve in rounds with straggler compaction (:func:`relight.fitting._driver.run_rounds`,
    the per-texel subsurface solve): a sample counts once on ``bar`` (a ``stage.Phase``, or None: silent) when
    its first round is done, so the bar's rate is the solve's and the phase completes with the first round;
    the samples that later rounds finish count on ``bar``'s follow-on "... (more steps)" (no total: how many
    straggle is known only as the rounds go), made when a later round first finishes a sample, so it never
    reads "compiling" (the program is compiled by then) and never shows an empty count."""

    def __init__(self, bar):
        self.bar, self.more, self.later = bar, None, False

    def chunk(self, first_round: bool, solved: int, finished: int) -> None:
        """A chunk of ``solved`` samples is through one round, ``finished`` of them converged."""
        if self.bar is None:
            return
        if first_round:
            self.bar.advance(solved)
            return
        self.later = True
        self._count(finished)

    def end(self, left: int) -> None:
        """The rounds are over with ``left`` samples still at the step limit: done, as far as the fit goes
        (already counted when the first round was the only one)."""
        if self.bar is not None and self.later:
            self._count(left)

    def _count(self, n: int) -> None:
        if n:
            self.more = self.more or self.bar.follow_on(" (more steps)")
            self.more.advance(n)

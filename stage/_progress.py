"""One progress protocol for every long-running call of the project.

A progress callback is any callable ``progress(phase, done, total)``:
``phase`` a short name of what is running ("light visibility", "simulate",
"fit ggx", "shading"), ``done`` the units of that phase finished so far
(cumulative, not an increment), ``total`` the units the phase will take (None
when unknown). A phase starts with ``done = 0``, reported before any of its
work (and so before its first JIT compile); each phase keeps its own count and
total, and phases may interleave (a fit's rungs over its blocks). A consumer
should time a phase's rate from its first ``done > 0``: the first unit pays
the compile (the CLI's bars read "compiling" until then). Work that only some
units need is a follow-on phase with no total (``Phase.follow_on``: a fit's
later rounds, "fit ggx (more steps)"), so no phase's count waits on it. Library functions
take ``progress=None`` (silent); the CLI passes progress bars
(``relight/cli/_progress.py``'s ``Bar``).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable


@runtime_checkable
class Progress(Protocol):
    """``progress(phase, done, total)``: see the module docstring."""

    def __call__(self, phase: str, done: int, total: int | None) -> None: ...


class Phase:
    """The counter of one phase: ``Phase(progress, "simulate", total)`` reports
    ``done = 0`` at once, then ``advance(n)`` adds ``n`` units and reports the
    running count. Silent when ``progress`` is None."""

    def __init__(self, progress: Progress | None, name: str, total: int | None = None):
        if progress is not None and not callable(progress):
            raise TypeError(f"progress must be a callable progress(phase, done, total) or None, got {progress!r}")
        self.progress, self.name, self.total, self.done = progress, str(name), total, 0
        self._follow: Phase | None = None
        if progress is not None:
            progress(self.name, 0, total)

    def advance(self, n: int = 1) -> None:
        self.done += int(n)
        if self.progress is not None:
            self.progress(self.name, self.done, self.total)

    def follow_on(self, suffix: str) -> Phase:
        """The phase ``name + suffix`` (same ``progress``, no total): work that only some of this phase's
        units need, such as a solver's later rounds for the samples its first round left unconverged,
        counted apart so that this phase's count, rate and ETA stay true (each unit counted once, when its
        first pass is done). Made at the first call, reporting ``done = 0`` then; the same object after,
        so every block of a fit adds to one count."""
        if self._follow is None:
            self._follow = Phase(self.progress, self.name + str(suffix))
        return self._follow

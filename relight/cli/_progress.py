"""Progress bars of the ``relight`` commands (tqdm, on stderr), which are themselves the ``progress`` callback
of every library call (``stage.Progress``), and the ``-qq`` rule for the summary line."""

from __future__ import annotations


# A phase's bar before its first unit is done: JAX is tracing and compiling, so a rate or an ETA from the
# time spent so far would be one of hours (the first chunk pays the compile); it says "compiling" instead.
def _waiting_format(total, label: str) -> str:
    return f"{{desc}}: {{n_fmt}}{'/{total_fmt}' if total else ''} [{label}, {{elapsed}}]"


class Bar:
    """Progress bars (tqdm, on stderr) that are themselves the ``progress`` callback of every library call:
    ``progress(phase, done, total)`` (``stage.Progress``, the project's one protocol). Each phase gets its
    own bar with its own total (a rung of ``--model auto``, a subsurface pass), made when the phase first
    reports and kept while its count goes on (a phase may span several blocks, interleaved with others).
    Until a phase's first unit is done its bar reads ``compiling`` with no rate or ETA; from then on the
    rate counts only the time since, so the compile does not enter the ETA. A phase without a total shows
    its running count. ``quiet``: no bars at all. ``file``: the stream (default: tqdm's, stderr).
    ``waiting``: what a bar says before its first unit ("compiling"; a reading phase: "reading").
    ``tqdm_options``: passed to each tqdm (tests: ``mininterval=0, miniters=1`` to draw every report)."""

    def __init__(self, total, desc, quiet, leave=False, file=None, waiting: str = "compiling", **tqdm_options):
        self._quiet, self._leave, self._file, self._waiting = bool(quiet), leave, file, str(waiting)
        self._options = {"mininterval": 0.5, "dynamic_ncols": True, **tqdm_options}
        self._bars: dict[str, object] = {}
        self._running: dict[str, bool] = {}
        self._last = str(desc)
        self._open(self._last, total, 0)

    def _open(self, phase: str, total, done: int) -> None:
        from tqdm.auto import tqdm

        fmt = _waiting_format(total, self._waiting)
        kw = {} if self._file is None else {"file": self._file}
        self._bars[phase] = tqdm(total=total, desc=phase, unit="it", leave=self._leave, disable=self._quiet,
                                 initial=int(done), bar_format=None if done else fmt, **self._options, **kw)
        self._running[phase] = bool(done)

    def _start_rate(self, phase: str, done: int) -> None:
        """The first unit of ``phase`` is done: its bar shows rate and ETA, timed from now."""
        b = self._bars[phase]
        self._running[phase] = True
        b.bar_format = None
        if b.disable:
            b.n = done
            return
        b.reset(total=b.total)  # the clock and the smoothed rate start now
        b.n = b.last_print_n = b.initial = int(done)
        b.refresh()

    def __enter__(self) -> Bar:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        for b in self._bars.values():
            b.close()

    def update(self, n: int = 1) -> None:
        """Add ``n`` units to the bar that last reported (the bar's own phase at first)."""
        b = self._bars[self._last]
        self(self._last, b.n + int(n), b.total)

    def __call__(self, phase: str, done: int, total: int | None) -> None:
        phase, done = str(phase), int(done)
        self._last = phase
        b = self._bars.get(phase)
        if b is None:
            first = next(iter(self._bars))
            if len(self._bars) == 1 and self._bars[first].n == 0 and not self._running[first]:
                # The command's own placeholder bar (nothing counted yet) becomes this phase's.
                self._bars.pop(first).close()
                self._running.pop(first)
            self._open(phase, total, done)
            return
        if total != b.total:
            b.total = total
            if not self._running[phase]:
                b.bar_format = _waiting_format(total, self._waiting)
        if not self._running[phase] and done > 0:
            self._start_rate(phase, done)
            return
        b.update(done - b.n)


def bar(total, desc, quiet, leave=False, file=None, waiting: str = "compiling") -> Bar:
    """A :class:`Bar` opened on ``desc`` with ``total`` units until a library phase reports."""
    return Bar(total, desc, quiet, leave, file, waiting)


def summary(args) -> bool:
    """Whether the one-line summary prints: unless ``-qq`` (``--quiet`` alone hides the bars only)."""
    return int(getattr(args, "quiet", 0) or 0) < 2

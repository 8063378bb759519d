"""Progress bars of the ``relight`` commands (tqdm, on stderr), which are themselves the ``progress`` callback
of every library call (``stage.Progress``), and the ``-qq`` rule for the summary line."""

from __future__ import annotations

import sys
import time


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
    ``live``: redrawn tqdm bars (True) or one plain line per phase (False, :class:`_PhaseLines`); default:
    bars when the stream is a terminal, lines when it is a file, a pipe or a CI log.
    ``tqdm_options``: passed to each tqdm (tests: ``mininterval=0, miniters=1`` to draw every report)."""

    def __init__(self, total, desc, quiet, leave=False, file=None, waiting: str = "compiling", live=None,
                 **tqdm_options):
        self._quiet, self._leave, self._file, self._waiting = bool(quiet), leave, file, str(waiting)
        self._options = {"mininterval": 0.5, "dynamic_ncols": True, **tqdm_options}
        self._bars: dict[str, object] = {}
        self._running: dict[str, bool] = {}
        self._last = str(desc)
        if live is None:  # redrawn bars on a terminal; one line per phase in a log or a pipe
            stream = file if file is not None else sys.stderr
            live = bool(getattr(stream, "isatty", lambda: False)())
        self._lines = None if live or self._quiet else _PhaseLines(file if file is not None else sys.stderr)
        self._open(self._last, total, 0)

    def _open(self, phase: str, total, done: int) -> None:
        from tqdm.auto import tqdm

        if self._lines is not None:
            self._bars[phase] = self._lines.open(phase, total, done)
            self._running[phase] = bool(done)
            return

        fmt = _waiting_format(total, self._waiting)
        kw = {} if self._file is None else {"file": self._file}
        self._bars[phase] = tqdm(total=total, desc=phase, unit="it", leave=self._leave, disable=self._quiet,
                                 initial=int(done), bar_format=None if done else fmt, **self._options, **kw)
        self._running[phase] = bool(done)

    def _start_rate(self, phase: str, done: int) -> None:
        """The first unit of ``phase`` is done: its bar shows rate and ETA, timed from now."""
        b = self._bars[phase]
        self._running[phase] = True
        if self._lines is not None:
            self._lines.advance(b, done, first=True)
            return
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
        if self._lines is not None:
            self._lines.close(self._bars.values())
            return
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
        if b is not None and done == 0 and b.n > 0:
            # The phase starts again (the second pass of fit_with_subsurface): a count and clock of its own,
            # the finished one's line out first.
            old = self._bars.pop(phase)
            self._running.pop(phase)
            if self._lines is not None:
                self._lines.close([old])
            else:
                old.close()
            b = None
        if b is None:
            first = next(iter(self._bars), None)
            if len(self._bars) == 1 and self._bars[first].n == 0 and not self._running[first]:
                # The command's own placeholder bar (nothing counted yet) becomes this phase's.
                placeholder = self._bars.pop(first)
                self._running.pop(first)
                if self._lines is None:
                    placeholder.close()
            self._open(phase, total, done)
            return
        if self._lines is not None:
            b.total = total
            self._lines.advance(b, done, first=not self._running[phase] and done > 0)
            self._running[phase] = self._running[phase] or done > 0
            return
        if total != b.total:
            b.total = total
            if not self._running[phase]:
                b.bar_format = _waiting_format(total, self._waiting)
        if not self._running[phase] and done > 0:
            self._start_rate(phase, done)
            return
        b.update(done - b.n)


class _Phase:
    """One phase's count in line mode: its name, total, count, start and first-unit times, and whether its
    line is out."""

    def __init__(self, phase: str, total, done: int):
        self.phase, self.total, self.n = phase, total, int(done)
        self.start = time.perf_counter()
        self.first = self.start if done else None
        self.last = self.start  # when the count last grew: a phase printed at the close ends there, not at the close
        self.printed = False


class _PhaseLines:
    """Progress where nothing is redrawn (a log file, a pipe, CI): one plain line per phase when it completes
    (its count reaches its total), or at the end for a phase without a total or left short, with the seconds
    it took and, apart, those before its first unit (JAX compiling): no cursor codes, no bars stacked by the
    dozen, no rate extrapolated from a phase's first seconds."""

    def __init__(self, stream):
        self.stream = stream

    def open(self, phase: str, total, done: int) -> _Phase:
        p = _Phase(phase, total, done)
        self._maybe_print(p)
        return p

    def advance(self, p: _Phase, done: int, first: bool = False) -> None:
        if first and p.first is None:
            p.first = time.perf_counter()
        if int(done) > p.n:
            p.last = time.perf_counter()
        p.n = int(done)
        self._maybe_print(p)

    def _maybe_print(self, p: _Phase) -> None:
        if not p.printed and p.total and p.n >= p.total:
            self._print(p)

    def _print(self, p: _Phase) -> None:
        p.printed = True
        count = f"{p.n}/{p.total}" if p.total else f"{p.n}"
        setup = "" if p.first is None or p.first - p.start < 0.05 else f" ({p.first - p.start:.1f} s before the first)"
        print(f"{p.phase}: {count} in {p.last - p.start:.1f} s{setup}", file=self.stream, flush=True)

    def close(self, phases) -> None:
        for p in phases:
            if not p.printed and p.n > 0:
                self._print(p)


def bar(total, desc, quiet, leave=False, file=None, waiting: str = "compiling") -> Bar:
    """A :class:`Bar` opened on ``desc`` with ``total`` units until a library phase reports."""
    return Bar(total, desc, quiet, leave, file, waiting)


def summary(args) -> bool:
    """Whether the one-line summary prints: unless ``-qq`` (``--quiet`` alone hides the bars only)."""
    return int(getattr(args, "quiet", 0) or 0) < 2

"""Per-stage timing and progress bars.

>>> timer = StageTimer()
>>> with timer.stage("load"):
...     pass
>>> "load" in timer.seconds
True

What a timer prints, all on stderr, nothing at all when ``quiet`` (CI, the service):

* ``[prtcore] <stage> starting`` when a stage begins and ``[prtcore] <stage>  1.23 s``
  when it ends (on a terminal or not: a log shows which stage is running);
* progress bars with an ETA over a stage's long loops (tqdm), only when stderr is a
  terminal. A terminal that reports a size of 0 × 0 (``script``, ``docker run -t``
  before the first resize) is taken as 80 × 24: tqdm draws nothing at that size.

Loops whose caller passes no timer get a bar through :func:`bar`, which uses the timer
of the stage running (the innermost :meth:`StageTimer.stage`).
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from typing import TypeVar

from tqdm import tqdm

T = TypeVar("T")

#: (columns, lines) of the terminal for the bars when it reports 0 (or cannot be asked)
FALLBACK_SIZE = (80, 24)

#: Called as ``callback(stage, fraction)`` with fraction in [0, 1]; used by the service
#: workers to publish progress and to cancel between stages (by raising).
ProgressCallback = Callable[[str, float], None]


@dataclass
class StageTimer:
    """Records wall time per named stage, in order; optionally reports to a callback."""

    quiet: bool = False
    callback: ProgressCallback | None = None
    seconds: dict[str, float] = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)
    #: how many times each stage ran (a keyframe bake runs the transport stages per keyframe)
    runs: dict[str, int] = field(default_factory=dict)

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Time the block as stage ``name``. ``seconds[name]`` accumulates over repeated
        runs (the report's stage times); the line printed at the end gives this run's own
        time, and for a repeated stage which run it was and the total so far."""
        if self.callback is not None:
            self.callback(name, 0.0)
        self._say(f"[prtcore] {name:<18s} starting")
        token = _ACTIVE.set(self)
        t0 = time.perf_counter()
        try:
            yield
        finally:
            dt = time.perf_counter() - t0
            _ACTIVE.reset(token)
            self.seconds[name] = self.seconds.get(name, 0.0) + dt
            self.runs[name] = self.runs.get(name, 0) + 1
        if self.callback is not None:
            self.callback(name, 1.0)
        line = f"[prtcore] {name:<18s} {dt:8.2f} s"
        if self.runs[name] > 1:
            line += f"  (run {self.runs[name]}; {self.seconds[name]:.2f} s in all)"
        self._say(line)

    def skip(self, name: str, why: str) -> None:
        self.skipped[name] = why
        self._say(f"[prtcore] {name:<18s}  skipped: {why}")

    def note(self, line: str) -> None:
        """A line of the run's own (a decision it took) among the stage lines, unless
        quiet."""
        self._say(line)

    def _say(self, line: str) -> None:
        """One line on stderr unless quiet; through tqdm so that an open bar is redrawn
        below it instead of being overwritten."""
        if not self.quiet:
            tqdm.write(line, file=sys.stderr)
            sys.stderr.flush()

    @property
    def bars(self) -> bool:
        """Whether this timer draws progress bars: not quiet and stderr is a terminal."""
        return not self.quiet and _stderr_is_tty()

    def bar(self, iterable: Iterable[T], desc: str, total: int | None = None) -> Iterable[T]:
        """Wrap ``iterable`` in a progress bar with elapsed time and ETA (when ``total``
        or ``len(iterable)`` is known), on stderr, only when :attr:`bars`."""
        if not self.bars:
            return tqdm(iterable, desc=desc, total=total, disable=True)
        cols, lines = _terminal_size()
        return tqdm(iterable, desc=desc, total=total, leave=False, file=sys.stderr,
                    ncols=cols, nrows=lines, mininterval=0.2)

    @property
    def total(self) -> float:
        return float(sum(self.seconds.values()))


#: The timer of the stage running in this context (set by :meth:`StageTimer.stage`).
_ACTIVE: ContextVar[StageTimer | None] = ContextVar("prtcore_stage_timer", default=None)


def bar(iterable: Iterable[T], desc: str, total: int | None = None) -> Iterable[T]:
    """A progress bar on the timer of the stage running (see :meth:`StageTimer.bar`), for
    loops whose caller passes no timer; ``iterable`` unchanged outside a stage."""
    timer = _ACTIVE.get()
    return iterable if timer is None else timer.bar(iterable, desc, total)


def _stderr_is_tty() -> bool:
    try:
        return bool(sys.stderr.isatty())
    except (AttributeError, ValueError):  # replaced or closed stderr
        return False


def _terminal_size() -> tuple[int, int]:
    """(columns, lines) for the bars: $COLUMNS / $LINES, else stderr's terminal, else
    FALLBACK_SIZE for whichever says 0 or cannot be read (tqdm draws nothing at 0 columns
    and hides every bar at 0 lines)."""
    try:
        size = os.get_terminal_size(sys.stderr.fileno())
    except (AttributeError, OSError, ValueError):
        size = os.terminal_size((0, 0))
    out = []
    for env, measured, fallback in (("COLUMNS", size.columns, FALLBACK_SIZE[0]),
                                    ("LINES", size.lines, FALLBACK_SIZE[1])):
        try:
            value = int(os.environ.get(env, "0"))
        except ValueError:
            value = 0
        value = value if value > 0 else measured
        out.append(value if value > 0 else fallback)
    return out[0], out[1]

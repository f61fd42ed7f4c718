"""Per-stage timing and progress bars.

>>> timer = StageTimer()
>>> with timer.stage("load"):
...     pass
>>> "load" in timer.seconds
True

Progress bars go to stderr through tqdm and are off when ``quiet`` (CI, the service) or
when stderr is not a terminal.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TypeVar

from tqdm import tqdm

T = TypeVar("T")

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
        t0 = time.perf_counter()
        try:
            yield
        finally:
            dt = time.perf_counter() - t0
            self.seconds[name] = self.seconds.get(name, 0.0) + dt
            self.runs[name] = self.runs.get(name, 0) + 1
        if self.callback is not None:
            self.callback(name, 1.0)
        if not self.quiet:
            line = f"[prtcore] {name:<18s} {dt:8.2f} s"
            if self.runs[name] > 1:
                line += f"  (run {self.runs[name]}; {self.seconds[name]:.2f} s in all)"
            print(line, file=sys.stderr)

    def skip(self, name: str, why: str) -> None:
        self.skipped[name] = why
        if not self.quiet:
            print(f"[prtcore] {name:<18s}  skipped: {why}", file=sys.stderr)

    def bar(self, iterable: Iterable[T], desc: str, total: int | None = None) -> Iterable[T]:
        """Wrap ``iterable`` in a progress bar (unless quiet or not a terminal)."""
        disable = self.quiet or not sys.stderr.isatty()
        return tqdm(iterable, desc=desc, total=total, disable=disable, leave=False,
                    file=sys.stderr)

    @property
    def total(self) -> float:
        return float(sum(self.seconds.values()))

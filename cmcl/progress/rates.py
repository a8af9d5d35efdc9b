"""Counters' growth per second over a trailing window of time: the service's rates (env steps/s, updates/s).

Where it sits: `services.observability.metrics.ServiceMetrics` (the Prometheus gauges `cmcl_*_per_second`, a 30 s
window) and `services.observability.progress_view.ProgressView` (the progress line and rows, a 10 s window) both read
their rates from one `WindowedRate`. A rate over the last refresh alone is 0 whenever no report arrived since, and the
learner reports once per call of `service.updates_per_call` updates, which on a loaded machine takes seconds: the line
and the dashboard then read "0 upd/s" at random while the run trained. The window spans several reports. Pure, no Ray.
"""

from __future__ import annotations

from collections import deque


class WindowedRate:
    """Growth per second of some counters over the trailing `window` seconds.

    `mark(now, counts)` records the counters' values at time `now` (seconds, increasing) and returns their growth
    per second since the base: the newest earlier mark at or before `now − window` (or the oldest one kept while the
    run is younger than the window); None at the first mark, when there is nothing to compare with."""

    def __init__(self, window: float) -> None:
        if not window > 0:
            raise ValueError(f"window must be > 0 seconds, got {window!r}")
        self.window = float(window)
        self.marks: deque[tuple[float, tuple[float, ...]]] = deque()

    @property
    def last(self) -> float | None:
        """Time of the newest mark, None before the first."""
        return self.marks[-1][0] if self.marks else None

    def mark(self, now: float, counts: tuple[float, ...]) -> tuple[float, ...] | None:
        marks = self.marks
        while len(marks) > 1 and marks[1][0] <= now - self.window:
            marks.popleft()
        rates = None
        if marks and now > marks[0][0]:
            t0, base = marks[0]
            rates = tuple((c - b) / (now - t0) for c, b in zip(counts, base, strict=True))
        marks.append((now, tuple(counts)))
        return rates

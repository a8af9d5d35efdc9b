"""A run's training clock over its segments, the same in both runners: `elapsed` goes on from the seconds of the
run's earlier segments (a resumed run's checkpoint keeps them), `segment` counts this command's, which
run.max_seconds bounds. Seconds of time.perf_counter."""

from __future__ import annotations

import time
from dataclasses import dataclass, field


@dataclass
class RunClock:
    before_s: float = 0.0  # training seconds of the run's earlier segments (0 for a new run)
    started: float = field(default_factory=time.perf_counter)  # this command's start

    def segment(self, now: float | None = None) -> float:
        """This command's seconds so far (at `now`, a perf_counter reading; None: now)."""
        return (time.perf_counter() if now is None else now) - self.started

    def elapsed(self, now: float | None = None) -> float:
        """The run's training seconds so far, over every segment."""
        return self.before_s + self.segment(now)

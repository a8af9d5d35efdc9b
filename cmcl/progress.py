"""Training progress shared by the inline loop and the service: moving averages of episode rows and the rule that
ends a run early once the task is solved.

Where it sits: `cmcl.loop.InlineLoop.run` and `services.supervisor.Supervisor.run` both keep a window of the last
`run.smoothing_window` episode rows (dicts with "coverage" in [0, 1] for the spread task) and ask `solved`.
No torch, no Ray.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np


def window_mean(window: Sequence[dict[str, Any]], key: str) -> float | None:
    """Mean of rows[key] over the window (None when the window is empty or its rows lack `key`)."""
    if not window or key not in window[0]:
        return None
    return float(np.mean([float(row[key]) for row in window]))


def solved(window: Sequence[dict[str, Any]], run: Any) -> bool:
    """Whether a full window (run.smoothing_window episodes) has mean final-step coverage >= run.stop_coverage.

    Always False when run.stop_coverage is 0 (off) or the rows carry no coverage (predator-prey).
    """
    if run.stop_coverage <= 0 or len(window) < run.smoothing_window:
        return False
    mean = window_mean(window, "coverage")
    return mean is not None and mean >= run.stop_coverage

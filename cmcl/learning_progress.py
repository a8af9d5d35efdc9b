"""Learning progress from the critics' TD error, and the rule that says learning has stopped progressing.

Where it sits: both runners feed it the learner's critic loss (the mean squared TD error of eq. 5, averaged over the
agents) as updates happen, with the episode count at that moment; `run.stop_progress` ends a run once `plateaued`
(the inline loop's and the supervisor's stop checks, beside `run.stop_coverage`). The agent-count curriculum
(`python -m cmcl stages`) uses it to decide when a stage is done, as SPMARL (Zhao et al., ICML 2025) drives its
curriculum over the number of agents by the critic's TD error rather than by the return, which grows with the number
of agents without the agents learning more.

Definition: episodes are cut into consecutive windows of `window` episodes; δ̄_k is the mean critic loss recorded
in window k. The learning progress of window k >= 1 is LP_k = |δ̄_k − δ̄_{k−1}| / δ̄_{k−1} (a relative change, in
either direction: under a sparse reward the TD error first rises as rewards appear, then falls as they are fitted).
Learning has stopped progressing once LP_k < `threshold` for `patience` consecutive windows. No torch, no Ray.
"""

from __future__ import annotations

import math
from typing import Any


class LearningProgress:
    """Windowed relative change of the critic loss; `plateaued` once it stays below `threshold` for `patience`
    windows. threshold 0 never plateaus (off)."""

    def __init__(self, threshold: float = 0.0, window: int = 500, patience: int = 3) -> None:
        if not (threshold >= 0 and math.isfinite(threshold)):
            raise ValueError(f"threshold must be a finite number >= 0, got {threshold!r}")
        for name, value in (("window", window), ("patience", patience)):
            if int(value) != value or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        self.threshold, self.window, self.patience = float(threshold), int(window), int(patience)
        self.window_index = 0  # the window now filling: episodes [k*window, (k+1)*window)
        self.total, self.count = 0.0, 0  # critic-loss sum and count of that window
        self.means: list[float] = []  # δ̄ of each finished window that held a value
        self.progress: list[float] = []  # LP of each finished window after the first
        self.below = 0  # consecutive finished windows with LP < threshold

    @classmethod
    def from_run_config(cls, run: Any) -> LearningProgress:
        """From `run.stop_progress`, `run.progress_window` and `run.progress_patience`."""
        return cls(run.stop_progress, run.progress_window, run.progress_patience)

    def record(self, episodes: int, critic_loss: float) -> None:
        """One update's critic loss (mean over agents, >= 0), made when `episodes` episodes had finished."""
        index = int(episodes) // self.window
        if index > self.window_index:
            self._close_window()
            self.window_index = index
        if math.isfinite(critic_loss):
            self.total += float(critic_loss)
            self.count += 1

    def _close_window(self) -> None:
        if self.count == 0:  # no update in that window (warm-up): nothing to compare
            return
        mean = self.total / self.count
        self.total, self.count = 0.0, 0
        if self.means and self.means[-1] > 0:
            lp = abs(mean - self.means[-1]) / self.means[-1]
            self.progress.append(lp)
            self.below = self.below + 1 if lp < self.threshold else 0
        self.means.append(mean)

    @property
    def plateaued(self) -> bool:
        """True once `patience` consecutive windows showed a learning progress below `threshold` (never when off)."""
        return self.threshold > 0 and self.below >= self.patience

    @property
    def last(self) -> float | None:
        """The newest window's learning progress, None before two windows have finished."""
        return self.progress[-1] if self.progress else None

    def state_dict(self) -> dict[str, Any]:
        return {"window_index": self.window_index, "total": self.total, "count": self.count,
                "means": list(self.means), "progress": list(self.progress), "below": self.below}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.window_index, self.count = int(state["window_index"]), int(state["count"])
        self.total = float(state["total"])
        self.means, self.progress = [float(x) for x in state["means"]], [float(x) for x in state["progress"]]
        self.below = int(state["below"])

"""Learning progress, windowed over episodes, and the rule that says learning has stopped progressing.

Where it sits: both runners feed it, as updates happen, the learner's critic loss (the mean squared TD error of
eq. 5) and its normalised TD error (that loss over the variance of the TD targets y of the same minibatch: the share
of the targets' variance the critic does not explain, 1 − R²), each averaged over the agents, with the episode count
at that moment; and, as episodes end, each episode's final-step coverage (spread) with its number.
`run.stop_progress` ends a run once `plateaued` (the inline loop's and the supervisor's stop checks, beside
`run.stop_coverage`). The agent-count curriculum (`python -m cmcl stages`) uses it to decide when a stage is done,
as SPMARL (Zhao et al., ICML 2025) drives its curriculum over the number of agents by the critic's TD error rather
than by the return, which grows with the number of agents without the agents learning more.

Definition: episodes are cut into consecutive windows of `window` episodes; m_k is a signal's mean over the values
recorded in window k. Its learning progress in window k >= 1 is
- `critic_loss`, `normalised_td`: the relative change LP_k = |m_k − m_{k−1}| / m_{k−1} (in either direction: under a
  sparse reward the TD error first rises as rewards appear, then falls as they are fitted);
- `coverage`: the absolute change LP_k = |m_k − m_{k−1}| (coverage is a fraction of the landmarks, already free of
  the agent count's scale).
All three are kept, window by window; `signal` (run.progress_signal, default coverage) names the one the rule reads:
learning has stopped progressing once its LP_k < `threshold` for `patience` consecutive windows. Why coverage
(lab/studies/learning_progress_windows.py, lab/RESULTS.md "The stage rule's signal", one seed, stages N = 2 then 4): the
raw critic loss grows with the value scale, so its relative change stayed 0.04–0.43 at N = 4 (coverage 0.67–0.77)
and never below 0.2 for three windows in a row; the normalised TD error's relative change was noisy (0.015–0.49 at
N = 4, 0.07 once at N = 2 while coverage rose by 0.35); the coverage's change stayed >= 0.033 while N = 2 learned and
<= 0.015 over N = 4's episodes 500–3,000, so 0.02 (patience 3) ends N = 4 at episode 2,000 and N = 2 never. No
torch, no Ray.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

from cmcl.replay.snapshot import OlderRunError, older_run

RELATIVE = {"critic_loss": True, "normalised_td": True, "coverage": False}  # LP: relative, else absolute change
SIGNALS = tuple(RELATIVE)  # run.progress_signal's values


def agent_mean(values: Iterable[float]) -> float:
    """The mean of the finite values of one update's per-agent statistic; nan when there is none (an agent whose
    targets had no variance in its minibatch has no normalised TD error)."""
    finite = [float(v) for v in values if math.isfinite(float(v))]
    return sum(finite) / len(finite) if finite else math.nan


class _Series:
    """One signal's window means and learning progress. `windows[i]` is the window index of `means[i]` (windows
    without a value are skipped); `progress` holds the learning progress of each window after the first with a value
(none for a relative change from a mean of 0)."""

    def __init__(self, relative: bool) -> None:
        self.relative = relative
        self.total, self.count = 0.0, 0  # sum and count of the open window's values
        self.means: list[float] = []
        self.windows: list[int] = []
        self.progress: list[float] = []

    def add(self, value: float) -> None:
        if math.isfinite(value):
            self.total += float(value)
            self.count += 1

    def change(self, before: float, after: float) -> float | None:
        """The learning progress from one window mean to the next; None for a relative change from 0."""
        if not self.relative:
            return abs(after - before)
        return abs(after - before) / before if before > 0 else None

    def close(self, window_index: int) -> float | None:
        """Close the open window (index `window_index`); its learning progress, None when there is none."""
        if self.count == 0:  # no value in that window (the warm-up's windows have no update): nothing to compare
            return None
        mean = self.total / self.count
        self.total, self.count = 0.0, 0
        lp = self.change(self.means[-1], mean) if self.means else None
        if lp is not None:
            self.progress.append(lp)
        self.means.append(mean)
        self.windows.append(window_index)
        return lp

    def state_dict(self) -> dict[str, Any]:
        return {"total": self.total, "count": self.count, "means": list(self.means), "windows": list(self.windows),
                "progress": list(self.progress)}

    def load_state_dict(self, state: dict[str, Any], window_index: int) -> None:
        self.total, self.count = float(state["total"]), int(state["count"])
        self.means, self.progress = [float(x) for x in state["means"]], [float(x) for x in state["progress"]]
        # states before the window indices were kept: the means are of the closed windows just before the open one
        windows = state.get("windows", range(window_index - len(self.means), window_index))
        self.windows = [int(w) for w in windows]


class LearningProgress:
    """Windowed learning progress of the critic loss, the normalised TD error and the coverage; `plateaued` once the
    `signal`'s stays below `threshold` for `patience` windows. threshold 0 never plateaus (off)."""

    def __init__(self, threshold: float = 0.0, window: int = 500, patience: int = 3,
                 signal: str = "coverage") -> None:
        if not (threshold >= 0 and math.isfinite(threshold)):
            raise ValueError(f"threshold must be a finite number >= 0, got {threshold!r}")
        for name, value in (("window", window), ("patience", patience)):
            if int(value) != value or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        if signal not in SIGNALS:
            raise ValueError(f"signal must be one of {list(SIGNALS)}, got {signal!r}")
        self.threshold, self.window, self.patience = float(threshold), int(window), int(patience)
        self.signal = signal
        self.window_index = 0  # the window now filling: episodes [k*window, (k+1)*window)
        self.series = {name: _Series(RELATIVE[name]) for name in SIGNALS}
        self.below = 0  # consecutive finished windows whose `signal` LP was < threshold

    @classmethod
    def from_run_config(cls, run: Any) -> LearningProgress:
        """From `run.stop_progress`, `run.progress_window`, `run.progress_patience` and `run.progress_signal`."""
        return cls(run.stop_progress, run.progress_window, run.progress_patience, run.progress_signal)

    def record(self, episodes: int, critic_loss: float, normalised_td: float = math.nan) -> None:
        """One update's critic loss (>= 0) and normalised TD error (nan: none), each the mean over the agents, made
        when `episodes` episodes had finished."""
        self._advance(int(episodes) // self.window)
        self.series["critic_loss"].add(critic_loss)
        self.series["normalised_td"].add(normalised_td)

    def record_episode(self, number: int, coverage: float | None) -> None:
        """The final-step coverage of episode `number` (1-based: `number` − 1 episodes had finished before it; None
        for a task without coverage). A value that comes after its window has closed (the service's episode reports
        and update reports race) counts in the open window."""
        self._advance((int(number) - 1) // self.window)
        if coverage is not None:
            self.series["coverage"].add(coverage)

    def _advance(self, index: int) -> None:
        if index <= self.window_index:
            return
        for name, series in self.series.items():
            lp = series.close(self.window_index)
            if name == self.signal and lp is not None:
                self.below = self.below + 1 if lp < self.threshold else 0
        self.window_index = index

    def close(self) -> None:
        """Close the open window as if the next had begun (a run that ended with its last window full: its values
        then count as a finished window)."""
        self._advance(self.window_index + 1)

    @property
    def plateaued(self) -> bool:
        """True once `patience` consecutive windows showed a learning progress below `threshold` (never when off)."""
        return self.threshold > 0 and self.below >= self.patience

    @property
    def means(self) -> list[float]:
        """The `signal`'s mean of each finished window that held a value."""
        return self.series[self.signal].means

    @property
    def progress(self) -> list[float]:
        """The `signal`'s learning progress of each finished window after its first."""
        return self.series[self.signal].progress

    @property
    def last(self) -> float | None:
        """The newest window's learning progress of `signal`, None before two windows have finished."""
        return self.progress[-1] if self.progress else None

    def windows(self) -> list[dict[str, Any]]:
        """Every finished window with a value of some signal, in order: {"window": k, "episodes": its end, and per
        signal its "<signal>" mean and "<signal>_lp" (None where it had none)}."""
        table: dict[int, dict[str, Any]] = {}
        for name, series in self.series.items():
            for i, (w, mean) in enumerate(zip(series.windows, series.means, strict=True)):
                row = table.setdefault(w, {"window": w, "episodes": (w + 1) * self.window,
                                           **{key: None for s in SIGNALS for key in (s, f"{s}_lp")}})
                row[name] = mean
                row[f"{name}_lp"] = series.change(series.means[i - 1], mean) if i else None
        return [table[w] for w in sorted(table)]

    def state_dict(self) -> dict[str, Any]:
        return {"window_index": self.window_index, "below": self.below, "signal": self.signal,
                "series": {name: series.state_dict() for name, series in self.series.items()}}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore a `state_dict()` (OlderRunError, one line, for a state without a signal's series, written before
        it was kept)."""
        missing = [name for name in SIGNALS if name not in state.get("series", {})]
        if missing:
            raise OlderRunError(older_run(f"learning progress state without the series {missing[0]!r}"))
        self.window_index = int(state["window_index"])
        for name in SIGNALS:
            self.series[name] = _Series(RELATIVE[name])
            self.series[name].load_state_dict(state["series"][name], self.window_index)
        if state["signal"] == self.signal:
            self.below = int(state["below"])
        else:  # another signal's count: this signal's trailing windows below the threshold
            self.below = 0
            for lp in reversed(self.progress):
                if lp >= self.threshold:
                    break
                self.below += 1

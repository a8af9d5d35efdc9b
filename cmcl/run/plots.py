"""Learning-curve PNGs from a run's metrics.jsonl (episode rows and progress rows of cmcl.run.rundir).

Where it sits: read-only consumer of run directories; used by `python -m cmcl evaluate` and by both runners at the end
of a run.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from cmcl.io.atomic import atomic_write_bytes
from cmcl.io.write_failure import RunWriteError
from cmcl.run.rundir import RunDirectory


def moving_average(values: np.ndarray, window: int) -> np.ndarray:
    """Trailing mean over up to `window` previous values: float64[T] -> float64[T]."""
    values = np.asarray(values, dtype=np.float64)
    if values.size == 0:
        return values
    sums = np.cumsum(np.insert(values, 0, 0.0))
    ends = np.arange(1, values.size + 1)
    starts = np.maximum(0, ends - window)
    return (sums[ends] - sums[starts]) / (ends - starts)


def episode_series(run: RunDirectory) -> dict[str, np.ndarray]:
    """Per-episode columns of a run: episode index, coverage, success, win, the task curriculum's stage the episode
    was played at (task_stage), and reward_<team>."""
    rows = list(run.rows("episode"))
    series: dict[str, list[float]] = {"episode": []}
    for row in rows:
        series["episode"].append(row["episodes"])
        for key in ("coverage", "success", "predator_win", "task_stage"):
            if key in row:
                series.setdefault(key, []).append(float(row[key]))
        for team, value in row.get("reward", {}).items():
            series.setdefault(f"reward_{team}", []).append(float(value))
    return {k: np.asarray(v, dtype=np.float64) for k, v in series.items()}


def plot_learning_curves(runs: Sequence[str | Path], out: str | Path, window: int = 100,
                         labels: Sequence[str] | None = None) -> Path:
    """Plot smoothed coverage / success / win rate and team reward of one or more runs into one PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = list(labels) if labels is not None else [Path(r).name for r in runs]
    fig, (ax_rate, ax_reward) = plt.subplots(1, 2, figsize=(11, 4))
    for run_path, label in zip(runs, labels, strict=True):
        series = episode_series(RunDirectory.open(run_path))
        x = series["episode"]
        for key in ("coverage", "success", "predator_win"):
            if key in series and series[key].size:
                ax_rate.plot(x, moving_average(series[key], window), label=f"{label} {key}")
        for key in sorted(k for k in series if k.startswith("reward_")):
            ax_reward.plot(x, moving_average(series[key], window), label=f"{label} {key[7:]}")
    ax_rate.set(xlabel="episode", ylabel=f"rate (moving average, {window} episodes)", ylim=(-0.02, 1.02))
    ax_reward.set(xlabel="episode", ylabel="team episode return (moving average)")
    for ax in (ax_rate, ax_reward):
        ax.grid(alpha=0.3)
        if ax.has_data():
            ax.legend(fontsize=7)
    fig.tight_layout()
    encoded = io.BytesIO()
    fig.savefig(encoded, format="png", dpi=100)
    plt.close(fig)
    atomic_write_bytes(out, encoded.getvalue())  # all or nothing; a full disk: RunWriteError naming the file
    return Path(out)


def curve_line(runs: Sequence[str | Path], out: str | Path, window: int = 100) -> str:
    """The line that names the learning curve `plot_learning_curves` wrote, or why it is not written (a full
    disk: the run's results before it stand)."""
    try:
        return f"learning curve: {plot_learning_curves(runs, out, window=window)}"
    except RunWriteError as err:
        return f"learning curve: not written ({err})"

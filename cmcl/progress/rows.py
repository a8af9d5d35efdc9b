"""Training progress, the same on both schedulers: episode rows, moving averages, the progress line
and the rule that ends a run early once the task is solved.

Where it sits: `services.runtime.supervisor.Supervisor` (on both schedulers) turns finished episodes into
metrics rows (`finished_episodes` -> `episode_rows`), keeps a window of the last `run.smoothing_window` rows (dicts
with "coverage" in [0, 1] for the spread task), prints `progress_line` and asks `solved`. No torch, no Ray.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from cmcl.replay.registry import COVERAGE_WAITS


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


# per-episode env statistics, and the task curriculum's stage of the episode (cmcl.rollout.task_curriculum)
EPISODE_STATS = ("coverage", "success", "collisions", "wall_hits", "captures", "task_stage")
# the ones the metrics report carries (services.observability.metrics schema)
REPORTED_STATS = ("coverage", "success", "task_stage")
# window means and their labels (task_stage: the mean task curriculum stage of the window's episodes)
WINDOW_KEYS = (("coverage", "cov"), ("success", "succ"), ("predator_win", "win"), ("task_stage", "stage"))


def finished_episodes(episode: dict[str, np.ndarray], teams: dict[str, list[int]],
                      stats: Sequence[str] = EPISODE_STATS) -> dict[str, Any]:
    """The M episodes that just ended, from a batched env's info["episode"] (return float32[M, N], coverage [M], ...):
    {"reward": {team: float64[M] (sum of the team's returns)}, stat: float64[M] for each of `stats` the env has,
    "win": {"predator": [M], "prey": [M]} for predator-prey}. This is the 'finished' section of a rollout report."""
    out: dict[str, Any] = {"reward": {t: episode["return"][:, idx].sum(1).astype(np.float64)
                                      for t, idx in teams.items()}}
    for key in stats:
        if key in episode:
            out[key] = episode[key].astype(np.float64)
    if "predator_win" in episode:
        win = episode["predator_win"].astype(np.float64)
        out["win"] = {"predator": win, "prey": 1.0 - win}
    return out


def episode_rows(finished: dict[str, Any], first_number: int, **fields: Any) -> list[dict[str, Any]]:
    """One 'episode' metrics row per finished episode, numbered from `first_number`; `fields` go in every row
    (the inline loop adds env_steps / updates / λ, the service the worker and its weight version)."""
    count = len(next(iter(finished["reward"].values())))
    rows = []
    for m in range(count):
        row: dict[str, Any] = {"kind": "episode", "episodes": first_number + m, **fields,
                               "reward": {t: float(v[m]) for t, v in finished["reward"].items()}}
        row.update({key: float(finished[key][m]) for key in EPISODE_STATS if key in finished})
        if "win" in finished:
            row["predator_win"] = float(finished["win"]["predator"][m])
        rows.append(row)
    return rows


def window_summary(window: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Means over a window of episode rows: coverage / success / predator_win where present, reward per team."""
    if not window:
        return {}
    out: dict[str, Any] = {key: window_mean(window, key) for key, _ in WINDOW_KEYS if key in window[0]}
    out["reward"] = {t: float(np.mean([r["reward"][t] for r in window])) for t in window[0]["reward"]}
    return out


def sampling_parts(ess: Sequence[float], reward_rows_sampled: Sequence[float],
                   reward_rows_buffer: Sequence[float], uniform: Sequence[bool]) -> list[str]:
    """The compact sampling part of a progress line, means over the agents that do not sample uniformly:
    ["ESS 0.42", "reward rows 0.02/0.18"], the ESS as a fraction of the buffer (1 = uniform) and the share of
    reward-bearing rows in a sampled minibatch / in the buffer (a curriculum that excludes the hard rows starves
    the learner of reward when the first is far below the second; lab/RESULTS.md, "Sampling and stalls").
    [] when every agent samples uniformly. Both runners' lines call it."""
    keep = [a for a, flat in enumerate(uniform) if not flat and a < len(ess)]
    if not keep:
        return []
    parts = [f"ESS {sum(ess[a] for a in keep) / len(keep):.2f}"]
    if len(reward_rows_sampled) == len(reward_rows_buffer) == len(ess):
        sampled = sum(reward_rows_sampled[a] for a in keep) / len(keep)
        parts.append(f"reward rows {sampled:.2f}/{sum(reward_rows_buffer[a] for a in keep) / len(keep):.2f}")
    return parts


def row_sampling_parts(row: dict[str, Any]) -> list[str]:
    """`sampling_parts` of an inline progress row's "sampling" diagnostics (an agent is uniform by its "modes"
    entry); [] when the row has none."""
    sampling = row.get("sampling") or {}
    ess = sampling.get("ess_fraction", [])
    modes = sampling.get("modes", [])
    return sampling_parts(ess, sampling.get("reward_rows_sampled", []), sampling.get("reward_rows_buffer", []),
                          [m == "uniform" for m in modes][:len(ess)])


def time_left(episodes: int, target: int, elapsed_s: float, max_seconds: float = 0.0,
              segment_s: float | None = None, learning: bool = True) -> str:
    """How long the run has left, in seconds: the wall-clock budget's rest ("left ≤ 183s (budget)") when it ends
    first, else the episode budget's rest at the rate so far ("left ~240s"); "" before the first episode, during
    the warm-up (`learning` false: no learner update yet, whose episodes cost a small part of a learning one's; the
    rate so far said "left ~0s") unless the budget tells, and once every episode is done.
    elapsed_s: the run's training seconds, over every segment of a resumed run; segment_s: this command's (the
    budget run.max_seconds is this command's); None: the same as elapsed_s (a run not resumed)."""
    used = elapsed_s if segment_s is None else segment_s
    by_episodes = elapsed_s / episodes * max(target - episodes, 0) \
        if episodes > 0 and elapsed_s > 0 and learning else None
    by_budget = max(max_seconds - used, 0.0) if max_seconds > 0 else None
    if by_budget is not None and (by_episodes is None or by_budget <= by_episodes):
        return f"left ≤ {by_budget:.0f}s (budget)"
    return "" if by_episodes is None or episodes >= target else f"left ~{by_episodes:.0f}s"


def progress_line(episodes: int, target: int, env_steps: int, updates: int, window: dict[str, Any], lam: float | None,
                  rates: dict[str, float], elapsed_s: float, extra: Sequence[str] = (), max_seconds: float = 0.0,
                  notes: Sequence[str] = (), segment_s: float | None = None) -> str:
    """One terminal line: counters, window means (see `window_summary`), λ (None: no rule of the run reads it, so
    the line leaves it out, and its `notes` with it), update and env-step rates, `extra`
    parts (the service adds buffer size, score age and weight lag), elapsed seconds (over every segment of a resumed
    run), the time left (`time_left`, with the wall-clock budget `max_seconds` of this command's `segment_s`, 0 =
    none) and `notes`: what is normal at this point
    of the run (the sampling rules' `early_note` while λ < 0.5, cmcl.replay.registry; its "cov may wait" only when
    `window` has a coverage)."""
    parts = [f"ep {episodes}/{target}", f"steps {env_steps}", f"upd {updates}"]
    parts += [f"{label} {window[key]:.2f}" for key, label in WINDOW_KEYS if window.get(key) is not None]
    parts += [f"R[{t}] {v:.1f}" for t, v in window.get("reward", {}).items()]
    parts += [f"λ {lam:.4f}"] if lam is not None else []
    parts += [f"{rates.get('updates_per_s', 0.0):.0f} upd/s",
              f"{rates.get('env_steps_per_s', 0.0):.0f} st/s", *extra, f"{elapsed_s:.0f}s"]
    left = time_left(episodes, target, elapsed_s, max_seconds, segment_s, learning=updates > 0)
    parts += [left] if left else []
    if lam is not None and lam < 0.5:  # a run without a coverage metric has no coverage to wait for
        parts += [note if "coverage" in window else note.replace(COVERAGE_WAITS, "") for note in notes]
    return " | ".join(parts)


class TrainingDiverged(RuntimeError):
    """The networks' weights are no longer finite (the actors' actions, or the learner's losses, are NaN / inf): the
    run ends with this one line, naming the episode, the updates and the learning rates; nothing of the diverged
    state is checkpointed (raised by the inline loop and by the service's supervisor)."""

    def __init__(self, config: Any, episodes: int, updates: int, what: str = "the actors' actions"):
        m = config.maddpg
        super().__init__(f"training diverged at episode {episodes}, after {updates} learner updates: {what} are NaN "
                         f"or infinite (the networks' weights are); maddpg.actor_lr = {m.actor_lr:g}, "
                         f"maddpg.critic_lr = {m.critic_lr:g}, maddpg.grad_clip = {m.grad_clip:g}: lower the "
                         "learning rates")


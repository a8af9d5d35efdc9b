"""The metrics rows an `InlineLoop` logs and prints: one row per finished episode, a 'progress' row every
`run.log_every` episodes (and at the end), and the progress row's terminal line.

Where it sits: `InlineLoop.env_step / progress_row / format_progress` (cmcl/loop/inline.py) are these functions; the
rows go to the run's metrics.jsonl (cmcl.io.metrics_log) and share their form with the service's
(cmcl.progress: `episode_rows`, `window_summary`, `progress_line`; cmcl.diagnostics: the replay's sampling,
priority and curriculum statistics). Each reads the loop's counters, λ, replay, window and last losses; an episode
row counts its episode (counters["episodes"]) and enters the moving-average window, a progress row starts LaBER's
picked-row share (`picked_rewarded`, float[N], over `picked_count` updates) afresh. elapsed_s is seconds.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cmcl.diagnostics import buffer_diagnostics
from cmcl.progress import episode_rows, finished_episodes, progress_line, row_sampling_parts, window_summary
from cmcl.replay.registry import early_notes, uses_lambda

# `loop` below is a cmcl.loop.inline.InlineLoop (typed Any: this module is below it, it does not import it)
Loop = Any


def finished_episode_rows(loop: Loop, info: dict[str, Any]) -> list[dict[str, Any]]:
    """One metrics row per finished episode (final-step coverage / success, or captures / win; returns)."""
    c = loop.counters
    rows = episode_rows(finished_episodes(info["episode"], loop.layout.teams), c["episodes"] + 1,
                        env_steps=c["env_steps"], updates=c["updates"], **{"lambda": loop.schedule.lam})
    c["episodes"] += len(rows)
    loop.window.extend(rows)
    return rows


def progress_row(loop: Loop, elapsed: float, rate: dict[str, float], segment: float | None = None) -> dict[str, Any]:
    """A 'progress' metrics row: counters, λ, losses, priority statistics and window means; elapsed: the training
    seconds over every segment of the run (resumes included), segment: this command's (None: the same)."""
    c = loop.counters
    row: dict[str, Any] = {"kind": "progress", **{k: c[k] for k in ("episodes", "env_steps", "updates")},
                           "lambda": loop.schedule.lam, "elapsed_s": elapsed,
                           "segment_s": elapsed if segment is None else segment, **rate,
                           "replay_size": loop.replay.size, "window": window_summary(loop.window),
                           **loop.last_stats}
    if loop.replay.size:  # "sampling" for every agent; "priority" / "curriculum" for ACL / CMCL agents
        row.update(buffer_diagnostics(loop.replay, loop.schedule.lam, loop.maddpg.updates))
        if loop.picked_count and "reward_rows_sampled" in row.get("sampling", {}):
            # LaBER picks in the learner: its agents' sampled share is the one measured in the picked minibatches
            measured = loop.picked_rewarded / loop.picked_count
            row["sampling"]["reward_rows_sampled"] = [round(float(measured[a]), 4) if pick else value
                                                      for a, (pick, value) in enumerate(zip(
                                                          loop.layout.select,
                                                          row["sampling"]["reward_rows_sampled"], strict=True))]
            loop.picked_rewarded, loop.picked_count = np.zeros(loop.layout.num_agents), 0
    return row


def format_progress(loop: Loop, row: dict[str, Any]) -> str:
    """One terminal line from a progress row."""
    return progress_line(row["episodes"], loop.config.run.episodes, row["env_steps"], row["updates"],
                         row["window"], row["lambda"] if uses_lambda(loop.layout.algorithms) else None, row,
                         row["elapsed_s"], extra=row_sampling_parts(row),
                         max_seconds=loop.config.run.max_seconds, notes=early_notes(loop.layout.algorithms),
                         segment_s=row.get("segment_s"))

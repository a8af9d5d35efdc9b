"""The service's progress line, rows and rates: what the supervisor prints and logs every report and returns in its
summary.

Where it sits: `services.runtime.supervisor.Supervisor` owns one `ProgressView`, feeds it the replay server's newest
status and report, and prints `line()`. Read-only over what it is given; the line's common part is `cmcl.progress.rows`.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from cmcl.progress.clock import RunClock
from cmcl.progress.rates import WindowedRate
from cmcl.progress.rows import progress_line, sampling_parts, window_summary
from cmcl.replay.messages import ReplayStatus
from services.observability.report_schema import Report


def replay_parts(status: ReplayStatus, report: Report | None, lags: dict[str, int]) -> list[str]:
    """The service's own fields of the line: buffer size, median teacher-score age (updates), the mean sampling ESS
    and reward-row shares (sampled/buffer) of the agents that do not sample uniformly
    (cmcl.progress.rows.sampling_parts), and each source's weight lag (versions)."""
    parts = [f"buf {status.size}"]
    replay = report.replay if report is not None else None
    ages = replay.score_age if replay is not None else None
    if ages is not None and len(ages):
        parts.append(f"score age {float(np.median(ages)):.0f} upd")
    if replay is not None and replay.agent_sampling_ess:
        agents = list(replay.agent_sampling_ess)
        ess = [replay.agent_sampling_ess[a] for a in agents]
        sampled, buffer = replay.reward_rows_sampled or {}, replay.reward_rows_buffer or {}
        shares = ([sampled[a] for a in agents], [buffer[a] for a in agents]) \
            if set(agents) <= set(sampled) and set(agents) <= set(buffer) else ([], [])
        parts += sampling_parts(ess, *shares, [e >= 1 for e in ess])  # a uniform sampler's ESS is 1 by construction
    if lags:
        parts.append("lag " + ",".join(f"{k}:{v}" for k, v in sorted(lags.items())))
    return parts


def sampling_row(report: Report | None, modes: list[str]) -> dict[str, Any]:
    """The service's progress row entries on the sampling distribution, in the inline rows' shape so that both
    runners' runs are measured alike (experiments.measures.sampling_over_training): {"sampling": {"modes",
    "ess_fraction", "reward_rows_sampled", "reward_rows_buffer": lists over agents in index order}} from the replay
    server's newest report, plus "kp_branches" (buffer share per KP branch, eq. 12) and "score_coverage" when it
    has them. modes: each agent's sampling distribution's name (cmcl.replay.sampling.sampling_name). {} before
    the first report with sampling diagnostics."""
    replay = report.replay if report is not None else None
    shares = (replay.agent_sampling_ess, replay.reward_rows_sampled, replay.reward_rows_buffer) if replay else ()
    if not shares or any(not share or len(share) != len(modes) for share in shares):
        return {}
    ess, sampled, buffer = ([float(share[str(a)]) for a in range(len(modes))] for share in shares)
    row: dict[str, Any] = {"sampling": {"modes": list(modes), "ess_fraction": ess, "reward_rows_sampled": sampled,
                                        "reward_rows_buffer": buffer}}
    if replay.kp_branches:
        row["kp_branches"] = dict(replay.kp_branches)
    if replay.score_coverage is not None:
        row["score_coverage"] = float(replay.score_coverage)
    return row

RATE_WINDOW_S = 10.0  # seconds the progress line's rates span (several learner calls: cmcl.progress.rates)


class ProgressView:
    """Env steps and updates per second over the last RATE_WINDOW_S seconds (refreshed at most every 0.5 s), and the
    progress line."""

    def __init__(self, episodes_target: int, clock: RunClock, status: ReplayStatus, sampling_modes: list[str],
                 max_seconds: float = 0.0, notes: list[str] | None = None, show_lambda: bool = True) -> None:
        """clock: the run's training clock (the supervisor's); sampling_modes: each agent's sampling distribution's
        name (cmcl.replay.registry.sampling_name); max_seconds: the run's wall-clock budget (0 = none); notes: what is
        normal while λ < 0.5 (cmcl.replay.registry.early_notes); show_lambda: whether a rule of the run reads λ
        (cmcl.replay.registry.uses_lambda), else the line leaves it out."""
        self.episodes_target, self.clock, self.sampling_modes = episodes_target, clock, list(sampling_modes)
        self.max_seconds, self.notes, self.show_lambda = float(max_seconds), list(notes or []), bool(show_lambda)
        self.rates = {"env_steps_per_s": 0.0, "updates_per_s": 0.0}
        self.window = WindowedRate(RATE_WINDOW_S)
        self.window.mark(clock.started, (status.env_steps, status.updates))

    def refresh(self, status: ReplayStatus) -> None:
        now = time.perf_counter()
        if now - self.window.last > 0.5:
            rates = self.window.mark(now, (status.env_steps, status.updates))
            if rates is not None:
                self.rates = {"env_steps_per_s": rates[0], "updates_per_s": rates[1]}

    def line(self, status: ReplayStatus, report: Report | None, lags: dict[str, int], window: Any) -> str:
        """One terminal line: env steps, episodes, coverage / win, reward, λ (when a rule reads it), rates, buffer,
        score age, lag; once every episode is collected, what the learner, the teachers and the ICM still owe their
        ratios before the run ends (`owed_part`)."""
        line = progress_line(status.episodes, self.episodes_target, status.env_steps, status.updates,
                             window_summary(window), status.lam if self.show_lambda else None, self.rates,
                             self.clock.elapsed(), replay_parts(status, report, lags), self.max_seconds, self.notes,
                             segment_s=self.clock.segment())
        owed = owed_part(status) if status.episodes >= self.episodes_target else ""
        return f"{line} | {owed}" if owed else line

    def row(self, status: ReplayStatus, report: Report | None) -> dict[str, Any]:
        """The progress row of metrics.jsonl: counters, rates, elapsed seconds (the run's, over every segment;
        segment_s: this command's) and the sampling entries
        (`sampling_row`) of the replay server's newest report."""
        now = time.perf_counter()
        return {"kind": "progress", **status.counters(), **self.rates, "elapsed_s": self.clock.elapsed(now),
                "segment_s": self.clock.segment(now), **sampling_row(report, self.sampling_modes)}


def owed_part(status: ReplayStatus) -> str:
    """After the last episode: "finishing: 373 updates, 45 teacher / ICM fit steps owed" (the run ends when both are
    below 1: services.runtime.supervisor), "" when nothing is owed."""
    owed = [f"{status.update_deficit:.0f} updates"] if status.update_deficit >= 1 else []
    owed += [f"{status.scoring_deficit:.0f} teacher / ICM fit steps"] if status.scoring_deficit >= 1 else []
    return f"finishing: {', '.join(owed)} owed" if owed else ""

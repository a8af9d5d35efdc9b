"""The replay server's metrics report: buffer, λ, difficulty / priority distributions, score age and coverage.

Where it sits: `services.roles.replay_server.ReplayServer.report` builds it every few seconds from its own parts, passed
in typed (the buffer, its `cmcl.scorers.scoring.ScoringState`, a `ReplayTallies` of its counters); the supervisor
applies the Report to the Prometheus metrics (`services.observability.metrics`). Read-only: the server passes the
per-row priority terms it has just recomputed at the current λ. Arrays are uniform subsamples of at most REPORT_SAMPLES
rows, drawn with the server's own generator.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from cmcl.replay.buffer import ReplayBuffer
from cmcl.replay.diagnostics import buffer_branch_shares, ess_fraction, replay_sampling_diagnostics
from cmcl.scorers.scoring import ScoringState
from services.observability.report_schema import CurriculumReport, FitReport, ReplayReport, Report

REPORT_SAMPLES = 512


@dataclass(frozen=True)
class ReplayTallies:
    """The replay server's running totals the report shows (since its first start; a restart restores them).

    inserts / samples: transitions accepted / handed to the learner; rejected: refused inputs per reason;
    stale_scores: score / |δ| updates dropped because their row was overwritten; teacher_steps / teacher_scores:
    fit steps handed out and rows scored per fold (length K, empty without teachers); icm_steps / icm_scores: the
    ICM's; losses: the last fit loss per model ("teacher_<k>", "icm").
    """

    inserts: int
    samples: int
    rejected: Mapping[str, int]
    stale_scores: int
    teacher_steps: tuple[int, ...]
    teacher_scores: tuple[int, ...]
    icm_steps: int
    icm_scores: int
    losses: Mapping[str, float]


def replay_report(replay: ReplayBuffer, scoring: ScoringState, tallies: ReplayTallies, *, lam: float,
                  updates: int, details: dict[str, Any] | None, rng: np.random.Generator, incarnation: str,
                  resumed: bool) -> Report:
    """The Report of a replay server now. details: `ReplayBuffer.recompute_priorities(lam, details=True)` output for
    the curriculum agents (None when there are none or the buffer is empty); updates: learner updates so far."""
    fields: dict[str, Any] = {"size": replay.size, "capacity": replay.capacity, "inserts": tallies.inserts,
                              "samples": tallies.samples, "rejected": dict(tallies.rejected),
                              "stale_scores": tallies.stale_scores}
    size = replay.size
    sampling = replay_sampling_diagnostics(replay)  # {} for an empty buffer
    for key, name in (("agent_sampling_ess", "ess_fraction"), ("reward_rows_sampled", "reward_rows_sampled"),
                      ("reward_rows_buffer", "reward_rows_buffer")):
        if sampling:
            fields[key] = {str(a): v for a, v in enumerate(sampling[name])}
    if details is not None:
        d = details
        pick = rng.integers(0, size, min(size, REPORT_SAMPLES))
        scored = d["scored"][pick]
        fields.update(difficulty=d["c_hat"][pick][scored], priority=d["priority"][pick],
                      kfold_priority=d["kp"][pick][scored], curiosity_priority=d["cp"][pick],
                      kp_branches=buffer_branch_shares(d["c_hat"], d["scored"], lam),
                      sampling_ess=float(np.mean(ess_fraction(
                          replay.sampling_distribution()[:, d["agents"]]))))  # per-agent α (A8), controls
    summary = scoring.summary(replay, updates, rng, REPORT_SAMPLES)
    fields.update({k: v for k, v in dataclasses.asdict(summary).items() if v is not None})
    teachers = {str(k): FitReport(steps=steps, scores=tallies.teacher_scores[k],
                                  loss=tallies.losses.get(f"teacher_{k}"))
                for k, steps in enumerate(tallies.teacher_steps)} if scoring.teacher_agents.size else None
    icm = FitReport(steps=tallies.icm_steps, scores=tallies.icm_scores,
                    loss=tallies.losses.get("icm")) if scoring.icm_agents.size else None
    return Report(source="replay", role="replay", incarnation=incarnation, resumed=resumed,
                  replay=ReplayReport(**fields), curriculum=CurriculumReport(lam=lam), teachers=teachers, icm=icm)

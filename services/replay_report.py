"""The replay server's metrics report: buffer, λ, difficulty / priority distributions, score age and coverage.

Where it sits: `services.replay_server.ReplayServer.report` calls `replay_report` on itself every few seconds; the
supervisor applies the Report to the Prometheus metrics (`services.metrics`). Read-only: the server passes the
per-row priority terms it has just recomputed at the current λ. Arrays are uniform subsamples of at most
REPORT_SAMPLES rows, drawn with the server's own generator.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cmcl.diagnostics import buffer_branch_shares, ess_fraction, replay_sampling_diagnostics
from services.report_schema import CurriculumReport, FitReport, ReplayReport, Report

REPORT_SAMPLES = 512


def replay_report(server: Any, details: dict[str, Any] | None) -> Report:
    """The Report of a `ReplayServer` now; details: `ReplayBuffer.recompute_priorities(lam, details=True)` output
    for the curriculum agents (None when there are none or the buffer is empty)."""
    replay: dict[str, Any] = {"size": server.replay.size, "capacity": server.replay.capacity,
                              "inserts": server.counters["inserts"], "samples": server.counters["samples"],
                              "rejected": dict(server.rejected), "stale_scores": server.stale_scores}
    size = server.replay.size
    sampling = replay_sampling_diagnostics(server.replay)  # {} for an empty buffer
    for key, name in (("agent_sampling_ess", "ess_fraction"), ("reward_rows_sampled", "reward_rows_sampled"),
                      ("reward_rows_buffer", "reward_rows_buffer")):
        if sampling:
            replay[key] = {str(a): v for a, v in enumerate(sampling[name])}
    if details is not None:
        d = details
        pick = server.rng.integers(0, size, min(size, REPORT_SAMPLES))
        scored = d["scored"][pick]
        replay.update(difficulty=d["c_hat"][pick][scored], priority=d["priority"][pick],
                      kfold_priority=d["kp"][pick][scored], curiosity_priority=d["cp"][pick],
                      kp_branches=buffer_branch_shares(d["c_hat"], d["scored"], server.schedule.lam),
                      sampling_ess=float(np.mean(ess_fraction(
                          server.replay.sampling_distribution()[:, d["agents"]]))))  # per-agent α (A8), controls
    if server.pacing.teachers and size:
        valid = server.replay.valid_slots()
        times = server.difficulty.stamps(valid, server.replay.generations(valid))
        replay["score_coverage"] = float(server.replay.storage.scored["difficulty"][:size][
            :, server.layout.teacher_agents].all(1).mean())
        scored = server.replay.storage.scored["difficulty"][:size][:, server.layout.teacher_agents].all(1)
        folds = server.replay.storage.fold[:size]
        replay["fold_score_coverage"] = {str(f): float(scored[folds == f].mean()) for f in np.unique(folds)}
        ages = server.counters["updates"] - times[times >= 0]
        if ages.size:
            replay["score_age"] = ages[server.rng.integers(0, ages.size, min(ages.size, REPORT_SAMPLES))]
    if server.pacing.icm is not None and size:
        valid = server.replay.valid_slots()
        stamps = server.curiosity_stamps.stamps(valid, server.replay.generations(valid))[:, 0]
        ages = server.counters["updates"] - stamps[stamps >= 0]
        if ages.size:
            replay["curiosity_age"] = ages[server.rng.integers(0, ages.size, min(ages.size, REPORT_SAMPLES))]
    if server.sample_ages.size:
        replay["sample_age"] = server.sample_ages
    teachers = {str(k): FitReport(steps=server.teacher_steps[k], scores=server.teacher_scores[k],
                                  loss=server.losses.get(f"teacher_{k}"))
                for k in range(len(server.pacing.teachers))} if server.pacing.teachers else None
    icm = FitReport(steps=server.counters["icm_steps"], scores=server.counters["icm_scores"],
                    loss=server.losses.get("icm")) if server.pacing.icm is not None else None
    return Report(source="replay", role="replay", incarnation=server.incarnation, resumed=server.resumed,
                  replay=ReplayReport(**replay), curriculum=CurriculumReport(lam=server.schedule.lam),
                  teachers=teachers, icm=icm)


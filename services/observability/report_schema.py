"""The metrics report as code: frozen dataclasses built by every role, and `Report.to_dict`.

Where it sits: every actor call returns one `Report`; the supervisor hands it to
`services.observability.metrics.ServiceMetrics.apply`, which turns it into metric updates. Reports are built by the
roles of this code base, so they are not validated again on arrival.

Kinds of value in the field comments: N, a cumulative total since the actor's process started (float >= 0;
ServiceMetrics turns totals into counter increments); x, a gauge (finite float); arr, array-like of finite
numbers, any shape, flattened to float64 [n] by the metrics; label, a str or int, exported as str.
A field left None is absent (`to_dict` omits it). Compare reports by their `to_dict()` (fields hold arrays).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

# ReplayReport's sample fields, in the order they are subsampled (the seeded draws follow it)
SAMPLE_KEYS = ("difficulty", "priority", "kfold_priority", "curiosity_priority", "score_age", "curiosity_age",
               "sample_age")


def _plain(value: Any) -> Any:
    """A section, a mapping of them or a leaf as plain data (sections via `to_dict`)."""
    if isinstance(value, _Section):
        return value.to_dict()
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    return value


class _Section:
    """Shared `to_dict` of the report dataclasses: the report keys of the fields that are not None."""

    def to_dict(self) -> dict[str, Any]:
        """This part of the report as a plain mapping keyed by the report keys (nested sections as mappings)."""
        return {f.metadata.get("key", f.name): _plain(getattr(self, f.name))
                for f in fields(self) if getattr(self, f.name) is not None}


# Every label value a labelled counter can take, so that the endpoint exports each series from the start (a panel
# shows 0, not "no data"): the reasons the replay server refuses an input for, the roles of the actors.
REJECT_REASONS = ("bad_chunk", "duplicate", "invalid", "bad_feedback", "bad_scores", "log_truncated")
ROLES = ("rollout", "replay", "learner", "teacher", "icm")


@dataclass(frozen=True)
class ReplayReport(_Section):
    """``replay``, sent by the replay server; the sample arrays hold one value per sampled buffer row."""

    size: float | None = None  # x >= 0: transitions stored
    capacity: float | None = None  # x >= 0: transitions storable
    inserts: float | None = None  # N: transitions accepted
    samples: float | None = None  # N: transitions sampled
    rejected: Mapping[str, float] | None = None  # {reason label: N}: inputs refused per reason (REJECT_REASONS)
    stale_scores: float | None = None  # N: score / |δ| updates dropped because their row was overwritten since
    score_coverage: float | None = None  # x in [0, 1]: fraction of the buffer with teacher scores
    difficulty: np.ndarray | None = None  # arr in [0, 1]: normalised teacher difficulty
    priority: np.ndarray | None = None  # arr >= 0: curriculum index CI
    kfold_priority: np.ndarray | None = None  # arr >= 0: K-fold priority KP
    curiosity_priority: np.ndarray | None = None  # arr >= 0: curiosity priority CP
    score_age: np.ndarray | None = None  # arr >= 0: learner updates since each row's teacher score
    curiosity_age: np.ndarray | None = None  # arr >= 0: learner updates since each row's curiosity score
    sample_age: np.ndarray | None = None  # arr >= 0: learner updates since insertion, of rows the learner sampled
    kp_branches: Mapping[str, float] | None = None  # {rising|falling|excluded: x in [0, 1]}: buffer share per branch
    fold_score_coverage: Mapping[str, float] | None = None  # {fold label: x in [0, 1]}: rows of fold scored
    sampling_ess: float | None = None  # x in [0, 1]: effective sample size of P / buffer size (1 = uniform)
    # per agent (label: agent index), cmcl.replay.diagnostics.replay_sampling_diagnostics, every agent's sampling
    # (uniform: 1):
    agent_sampling_ess: Mapping[str, float] | None = None  # {agent: x in [0, 1]}: ESS of the agent's P / buffer size
    reward_rows_sampled: Mapping[str, float] | None = None  # {agent: x in [0, 1]}: P-mass on rows with reward > 0
    reward_rows_buffer: Mapping[str, float] | None = None  # {agent: x in [0, 1]}: buffer share of rows with reward > 0


@dataclass(frozen=True)
class CurriculumReport(_Section):
    """``curriculum``, sent by the replay server (which owns λ)."""

    lam: float | None = field(default=None, metadata={"key": "lambda"})  # x >= 0, key "lambda": λ


@dataclass(frozen=True)
class FitReport(_Section):
    """``icm``, and each entry of ``teachers`` ({teacher id label: FitReport}): one model's fitting and scoring."""

    steps: float | None = None  # N: fit steps
    scores: float | None = None  # N: rows scored (teachers) / curiosity rewards returned (ICM)
    loss: float | None = None  # x: last fit loss (ICM: inverse + forward)


@dataclass(frozen=True)
class LearnerReport(_Section):
    """``learner``, sent by the learner."""

    updates: float | None = None  # N: update steps (all agents at once)
    weight_version: int | None = None  # int >= 0: the version last published
    losses: Mapping[str, Mapping[str, float]] | None = None  # {agent label: {kind label: x}}, kinds critic, actor,
    # critic_normalised (the critic's mean squared TD error over its targets' variance; absent when they had none),
    # and with maddpg.assignment_loss > 0 assignment, assignment_accuracy (services.roles.learner.last_losses)
    busy_s: float | None = None  # N: wall seconds inside update calls (the rest of the time it waited for batches)
    busy_cpu_s: float | None = None  # N: CPU seconds of those calls (the thread that ran them)
    intrinsic_reward: float | None = None  # x: the last update's mean coef(t)·ρ added to a curiosity agent's own
    # reward (icm.intrinsic_reward_coef > 0; docs/ALGORITHM.md §3.4), None without it


@dataclass(frozen=True)
class FinishedEpisodes(_Section):
    """``rollout.finished``: one value per episode finished since the previous report."""

    coverage: np.ndarray | None = None  # arr in [0, 1]: landmark cover rate at the final step (spread)
    success: np.ndarray | None = None  # arr in [0, 1]: all landmarks covered (spread)
    reward: Mapping[str, np.ndarray] | None = None  # {team label: arr}: team episode return
    win: Mapping[str, np.ndarray] | None = None  # {team label: arr in [0, 1]}: episode won (tag)
    # arr >= 0: the task curriculum stage it was played at (cmcl.rollout.task_curriculum)
    task_stage: np.ndarray | None = None


@dataclass(frozen=True)
class RolloutReport(_Section):
    """``rollout``, sent by each rollout worker."""

    env_steps: float | None = None  # N: environment steps (per world)
    episodes: float | None = None  # N: episodes finished
    finished: FinishedEpisodes | None = None


@dataclass(frozen=True)
class Report(_Section):
    """One actor report: who sent it, then one optional section per kind of role."""

    source: str = "default"  # label of the sender (e.g. "rollout-0"); keys the counter bookkeeping
    role: str = "unknown"  # label: rollout | replay | teacher | icm | learner | ... (of cmcl_actor_restarts_total)
    incarnation: str | None = None  # label, new in every actor __init__: a change counts one restart
    resumed: bool = False  # the new incarnation restored its totals from a checkpoint
    weight_version: int | None = None  # int >= 0: policy version in use (cmcl_weight_version_lag{actor=source})
    checkpoints_refused: float | None = None  # N: checkpoint files this incarnation refused when it started
    replay: ReplayReport | None = None
    curriculum: CurriculumReport | None = None
    teachers: Mapping[str, FitReport] | None = None
    icm: FitReport | None = None
    learner: LearnerReport | None = None
    rollout: RolloutReport | None = None

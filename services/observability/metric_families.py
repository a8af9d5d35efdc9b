"""The metric families of the CMCL service: names, help texts, labels and histogram buckets, in one place.

Where it sits: `services.observability.metrics.ServiceMetrics` calls `define_metrics` once on its private registry and
updates the returned metrics from actor reports (services/observability/report_schema.py). `NumpyHistogram` is a
label-less histogram whose buckets grow from whole numpy arrays (the replay samples of a report) in one vectorised step.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Iterator

import numpy as np
from prometheus_client import CollectorRegistry, Counter, Gauge
from prometheus_client.metrics_core import HistogramMetricFamily, Metric
from prometheus_client.registry import Collector
from prometheus_client.utils import floatToGoString

from services.observability.report_schema import REJECT_REASONS, ROLES

UNIT_BUCKETS = tuple(round(0.05 * i, 2) for i in range(1, 21))  # [0.05 .. 1.0]
CI_BUCKETS = tuple(round(0.1 * i, 1) for i in range(1, 16))  # [0.1 .. 1.5]
AGE_BUCKETS = (0, 1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000, 10000)

HISTOGRAMS = {  # sample key of ReplayReport (SAMPLE_KEYS) -> (metric name, help, bucket upper bounds)
    "difficulty": ("cmcl_difficulty", "Normalised teacher difficulty of buffer samples (0-1).", UNIT_BUCKETS),
    "priority": ("cmcl_priority", "Curriculum index CI of buffer samples.", CI_BUCKETS),
    "kfold_priority": ("cmcl_kfold_priority", "K-fold priority KP of buffer samples.", UNIT_BUCKETS),
    "curiosity_priority": ("cmcl_curiosity_priority", "Curiosity priority CP of buffer samples.", UNIT_BUCKETS),
    "score_age": ("cmcl_teacher_score_age_updates", "Learner updates since each teacher score was computed.",
                  AGE_BUCKETS),
    "curiosity_age": ("cmcl_curiosity_score_age_updates", "Learner updates since each curiosity score was computed.",
                      AGE_BUCKETS),
    "sample_age": ("cmcl_sample_age_updates", "Learner updates since insertion of the rows the learner sampled.",
                   AGE_BUCKETS),
}


class NumpyHistogram(Collector):
    """A label-less histogram whose bucket counts grow from whole numpy arrays (one searchsorted per call)."""

    def __init__(self, name: str, documentation: str, buckets: tuple[float, ...]):
        self.name, self.documentation = name, documentation
        self._upper = np.asarray([*sorted(float(b) for b in buckets), math.inf])
        self._counts = np.zeros(self._upper.size, dtype=np.int64)
        self._sum = 0.0
        self._lock = threading.Lock()

    def observe_many(self, values: np.ndarray) -> None:
        """Add finite `values` [n] to the buckets (bucket i counts upper[i-1] < v <= upper[i])."""
        idx = np.searchsorted(self._upper, values, side="left")
        counts = np.bincount(idx, minlength=self._upper.size)
        with self._lock:
            self._counts += counts
            self._sum += float(values.sum())

    def collect(self) -> Iterator[Metric]:
        """Yield the histogram with cumulative bucket counts."""
        with self._lock:
            cumulative = np.cumsum(self._counts)
            total = self._sum
        buckets = [(floatToGoString(le), float(c)) for le, c in zip(self._upper, cumulative, strict=True)]
        yield HistogramMetricFamily(self.name, self.documentation, buckets=buckets, sum_value=total)


def define_metrics(r: CollectorRegistry) -> tuple[dict[str, Gauge], dict[str, Counter], dict[str, NumpyHistogram]]:
    """Create every metric of the service in registry `r`: (gauges, counters, histograms), each keyed by the
    short name ServiceMetrics plans with (histograms by their ReplayReport sample key)."""
    g = lambda name, doc, labels=(): Gauge(name, doc, labels, registry=r)  # noqa: E731
    c = lambda name, doc, labels=(): Counter(name, doc, labels, registry=r)  # noqa: E731
    gauges = {
        "replay_size": g("cmcl_replay_size", "Transitions stored in the replay buffer."),
        "replay_capacity": g("cmcl_replay_capacity", "Capacity of the replay buffer in transitions."),
        "score_coverage": g("cmcl_teacher_score_coverage", "Fraction of the buffer with teacher scores (0-1)."),
        "fold_score_coverage": g("cmcl_fold_score_coverage",
                                 "Fraction of each fold's rows with a teacher difficulty score (0-1).", ["fold"]),
        "kp_branch": g("cmcl_kp_branch_fraction", "Fraction of the scored buffer in each KP branch (eq. 12): "
                       "rising (c <= lambda), falling (lambda < c < 2 lambda), excluded (c >= 2 lambda).", ["branch"]),
        "sampling_ess": g("cmcl_sampling_ess_fraction",
                          "Effective sample size of the curriculum sampling distribution / buffer size (1 = uniform)."),
        "agent_sampling_ess": g("cmcl_agent_sampling_ess_fraction", "Effective sample size of each agent's "
                                "sampling distribution / buffer size (1 = uniform; PER and curriculum below 1).",
                                ["agent"]),
        "reward_rows": g("cmcl_reward_rows_fraction", "Share of rows whose reward for the agent is > 0 (a covered "
                         "landmark, a capture): expected in a sampled minibatch (where=sampled) and in the buffer "
                         "(where=buffer).", ["agent", "where"]),
        "lambda": g("cmcl_curriculum_lambda", "Curriculum factor lambda owned by the replay server."),
        "teacher_loss": g("cmcl_teacher_loss", "Last fit loss of each teacher critic.", ["teacher"]),
        "icm_loss": g("cmcl_icm_loss", "Last ICM training loss (inverse + forward)."),
        "learner_loss": g("cmcl_learner_loss", "Last learner loss per agent and kind.", ["agent", "kind"]),
        "intrinsic_reward": g("cmcl_intrinsic_reward", "Mean curiosity reward coef * rho the learner's last update "
                              "added to an agent's own reward (icm.intrinsic_reward_coef > 0)."),
        "weight_lag": g("cmcl_weight_version_lag",
                        "Policy versions the actor is behind the learner's last published weights.", ["actor"]),
        "coverage_rate": g("cmcl_coverage_rate", "Landmark cover rate at the final step, moving average."),
        "success_rate": g("cmcl_success_rate", "Fraction of episodes with all landmarks covered, moving avg."),
        "win_rate": g("cmcl_win_rate", "Episode win rate per team, moving average.", ["team"]),
        "episode_reward": g("cmcl_episode_reward", "Team episode return, moving average.", ["team"]),
        "updates_per_second": g("cmcl_updates_per_second", "Learner updates per second (recent)."),
        "env_steps_per_second": g("cmcl_env_steps_per_second", "Environment steps per second (recent)."),
    }
    counters = {
        "replay_inserts": c("cmcl_replay_inserts_total", "Transitions accepted by the replay server."),
        "replay_samples": c("cmcl_replay_samples_total", "Transitions sampled from the replay buffer."),
        "replay_rejected": c("cmcl_replay_rejected_total", "Inputs refused by the replay server (bad input).",
                             ["reason"]),
        "replay_stale_scores": c("cmcl_replay_stale_scores_total",
                                 "Score and |TD| updates dropped because their row was overwritten since they were "
                                 "handed out: expected by design, tens of thousands per run, not a fault."),
        "teacher_steps": c("cmcl_teacher_steps_total", "Teacher critic fit steps.", ["teacher"]),
        "teacher_scores": c("cmcl_teacher_scores_total", "Transitions scored by each teacher.", ["teacher"]),
        "icm_steps": c("cmcl_icm_steps_total", "ICM training steps."),
        "curiosity_scores": c("cmcl_curiosity_scores_total", "Curiosity rewards computed by the ICM actor."),
        "learner_updates": c("cmcl_learner_updates_total", "Learner update steps (all agents at once)."),
        "learner_busy_seconds": c("cmcl_learner_busy_seconds_total", "Wall seconds the learner spent in update calls "
                                  "(its rate: the share of time busy; 1 minus it, the share spent waiting)."),
        "learner_busy_cpu_seconds": c("cmcl_learner_busy_cpu_seconds_total",
                                      "CPU seconds of the learner's update calls (the thread that ran them)."),
        "env_steps": c("cmcl_env_steps_total", "Environment steps taken by rollout workers (per world)."),
        "episodes": c("cmcl_episodes_total", "Episodes finished by rollout workers."),
        "restarts": c("cmcl_actor_restarts_total", "Actor restarts seen as a new incarnation.", ["role"]),
        "checkpoints_refused": c("cmcl_checkpoints_refused_total",
                                 "Checkpoint files refused by their manifest check when a role started.", ["role"]),
        "reports": c("cmcl_metrics_reports_total", "Reports applied to the metrics endpoint."),
    }
    for label, values in (("replay_rejected", REJECT_REASONS), ("restarts", ROLES), ("checkpoints_refused", ROLES)):
        for value in values:  # every series exists from the start: a panel shows 0, not "no data"
            counters[label].labels(value)
    histograms = {key: NumpyHistogram(*spec) for key, spec in HISTOGRAMS.items()}
    for hist in histograms.values():
        r.register(hist)
    return gauges, counters, histograms

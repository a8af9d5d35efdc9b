"""Learner: updates every agent's actor and critic in one batched MADDPG step per minibatch; publishes weights.

Where it sits: replay -> learner -> (|δ| back to replay, weights to rollout workers / teachers). The shell around
`cmcl.learners.network_steps.learner_update`, the same function the inline loop calls. The supervisor keeps two update
calls in flight, so the replay server samples the next batches while this one computes (prefetch). Weights are
published once per version as {"version", "weights"} (cmcl.learners.weights). Its report counts the wall and CPU
seconds spent inside update calls (`busy_s`, `busy_cpu_s`): the rest of the wall clock it waited for batches.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from cmcl.learners import network_steps
from cmcl.learners.entity.assignment import STATS as ASSIGNMENT_STATS
from cmcl.learners.weights import published_weights
from cmcl.replay.messages import ONLINE_TD, LearnerBatch, LearnerFeedback, RuleScore, Scorer, Scores, ScoreWork
from cmcl.run.warm_start import warm_start_from_config
from cmcl.system import build_maddpg, layout_of
from services.observability.report_schema import LearnerReport, Report
from services.runtime.common import actor_setup, load_state, new_incarnation, save_state


def last_losses(stats: dict[str, Any], agent: int) -> dict[str, float]:
    """One agent's losses of an update, as its report carries them: "critic", "actor" and, when its targets had some
    variance, "critic_normalised" (the critic's normalised TD error, which run.progress_signal = "normalised_td"
    reads; a report's numbers are finite); with maddpg.assignment_loss > 0 also "assignment" (the CE) and
    "assignment_accuracy" (when the agent had a row), cmcl.learners.entity.assignment."""
    losses = {"critic": float(stats["critic_loss"][agent]), "actor": float(stats["actor_loss"][agent])}
    normalised = float(stats["critic_loss_normalised"][agent])
    losses = {**losses, "critic_normalised": normalised} if np.isfinite(normalised) else losses
    for key in ASSIGNMENT_STATS:  # maddpg.assignment_loss > 0 only; accuracy NaN: the agent had no row
        if key in stats and np.isfinite(stats[key][agent]):
            losses[key.removesuffix("_loss")] = float(stats[key][agent])
    return losses


class Learner:
    """The MADDPG learner actor. `checkpoint_path`: where `save()` writes and `__init__` restores from."""

    def __init__(self, config: Any, seed: int, checkpoint_path: str | None = None):
        self.config = cfg = actor_setup(config)
        self.incarnation, self.checkpoint_path = new_incarnation(), checkpoint_path
        self.layout = layout_of(cfg)
        self.maddpg = build_maddpg(cfg, self.layout, seed)
        self.version, self.losses = 0, {}
        self.intrinsic_reward: float | None = None  # the last update's mean coef·ρ (network_steps.learner_update)
        self.busy_s = self.busy_cpu_s = 0.0  # wall / CPU (this thread) seconds inside update calls with a batch
        state, refused = load_state(checkpoint_path)
        self.checkpoints_refused = len(refused)  # files refused at this start (manifest checks)
        self.resumed = state is not None
        if state is not None:
            self.maddpg.load_state_dict(state["maddpg"])
            self.version = int(state["version"])
            self.busy_s, self.busy_cpu_s = float(state.get("busy_s", 0.0)), float(state.get("busy_cpu_s", 0.0))
        else:  # a fresh run (or a restart before the first checkpoint): the same warm start, if any
            warm_start_from_config(cfg.run.init_from, self.maddpg)

    def update(self, batch: LearnerBatch | None) -> tuple[LearnerFeedback | None, Report]:
        """Run one MADDPG update per minibatch of `batch` ([n, N, S, ...] arrays); None does nothing.

        Returns (feedback for the replay server: |δ| float32[n, N, S] of each sampled row, and the rules' own
        learner scores of them, metrics report).
        """
        if batch is None:
            return None, self.report()
        started, started_cpu = time.perf_counter(), time.thread_time()
        use_weights = any(self.layout.importance_weights)
        picked = []  # the slots and generations each minibatch trained on (LaBER picks them among candidates)
        stats: dict[str, Any] = {}
        for i in range(batch.count):
            minibatch, slots, generations = network_steps.choose_minibatch(self.maddpg, batch, i, use_weights,
                                                                           self.layout.select, self.layout.pick)
            stats = network_steps.learner_update(self.maddpg, minibatch, self.layout.icm_agents,
                                                 self.config.icm.intrinsic_coef(self.maddpg.updates))
            picked.append((slots, generations, stats["td_abs"],
                           network_steps.rule_scores(self.layout.rule_scores, stats, minibatch)))
        slots, generations = np.stack([p[0] for p in picked]), np.stack([p[1] for p in picked])
        td = np.stack([p[2] for p in picked]).astype(np.float32)
        own = tuple(RuleScore(s.name, np.stack([p[3][s.name] for p in picked])) for s in self.layout.rule_scores)
        # ACL td_self: the online critics score the rows they were given, after the updates (the scorer this role
        # hosts; the rows it has never scored come through `score`, before anything samples them)
        scores = self.score(batch.score)[0] if batch.score is not None else None
        self.version += 1
        self.losses = {f"agent_{a}": last_losses(stats, a) for a in range(self.layout.num_agents)}
        self.intrinsic_reward = stats.get("intrinsic_reward", self.intrinsic_reward)
        self.busy_s += time.perf_counter() - started
        self.busy_cpu_s += time.thread_time() - started_cpu
        return LearnerFeedback(slots, generations, td, self.losses, self.incarnation, own, scores), self.report()

    scorer = Scorer(ONLINE_TD)  # the scorer this role hosts: the online critics, writing the td_abs column (td_self)

    def score(self, work: ScoreWork | None, published: dict[str, Any] | None = None
              ) -> tuple[Scores | None, Report]:
        """The online critics' |y − Q_v(s, a)| float32[M, N] of work.score's rows, as Scores (ACL td_self; no fit:
        the critics train in `update`); the role's own weights, so `published` is not needed."""
        if work is None:
            return None, self.report()
        td_rows = network_steps.online_td_abs(self.maddpg, work.score.rows).astype(np.float32)  # [M, N]
        return Scores(self.scorer, work.score.slots, work.score.generations, td_rows, work.updates, 0.0,
                      self.incarnation), self.report()

    def publish(self) -> dict[str, Any]:
        """The current weights with their version (the supervisor puts this in the object store)."""
        return {"version": self.version, "weights": published_weights(self.maddpg)}

    def report(self) -> Report:
        """Metrics report (cumulative updates, busy seconds, published version, last losses per agent, the last
        intrinsic reward)."""
        return Report(source="learner", role="learner", incarnation=self.incarnation, resumed=self.resumed,
                      checkpoints_refused=self.checkpoints_refused,
                      learner=LearnerReport(updates=int(self.maddpg.updates), weight_version=self.version,
                                            losses=self.losses, busy_s=self.busy_s, busy_cpu_s=self.busy_cpu_s,
                                            intrinsic_reward=self.intrinsic_reward))

    def save(self) -> str | None:
        """Write the learner checkpoint atomically (torch.save of plain state dicts)."""
        return save_state(self.checkpoint_path, {"maddpg": self.maddpg.state_dict(), "version": self.version,
                                                 "busy_s": self.busy_s, "busy_cpu_s": self.busy_cpu_s})

"""Replay server: owns the buffer, folds, score columns, λ, every sampler and the rate limiters.

Where it sits: the hub of the flow, and a shell: dedupe, pacing and status around the replay side of Algorithm 1's
steps (`cmcl.replay.steps`, the same functions the inline loop calls). Rollout `Chunk`s come in (`insert`,
validated by `cmcl.io.codec.check_chunk`, idempotent by writer / incarnation / seq); teachers and the ICM ask for
work (`teacher_work`, `icm_work`) and send scores back keyed by (slot, generation), stale ones dropped
(`write_teacher_scores`, `write_curiosity`); the learner receives prioritized `LearnerBatch`es (`sample`) and
returns |δ| (`learner_result`). Priorities are recomputed in bulk when λ or scores changed, at most every
`service.recompute_every` inserts. λ advances with the env steps accepted here.

Distributed deviation from §3.8 (ALGORITHM.md §3.9), measured by `cmcl_teacher_score_age_updates`: teacher k
scores rows of the other folds asynchronously; c_j is (K−1)·mean over the blind teachers that have scored j so
far (`cmcl.replay.difficulty.DifficultyTable`); new rows sit at ε_p until a teacher has scored them.
Every method returns (or ends with) a small status dict the supervisor uses to pace its calls.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from cmcl.io import codec
from cmcl.messages import (
    CuriosityWork,
    MessageError,
    TeacherWork,
    check_curiosity_scores,
    check_feedback,
    check_teacher_scores,
)
from cmcl.replay import steps as buffer
from cmcl.replay.difficulty import DifficultyTable, ScoreStamps
from cmcl.replay.priority import uses_curriculum
from cmcl.system import agent_layout, beta_is, build_replay, build_schedule, make_batched_env
from services.common import actor_setup, new_incarnation
from services.replay_pacing import ReplayPacing
from services.report_schema import CurriculumReport, FitReport, ReplayReport, Report

REPORT_SAMPLES = 512


class ReplayServer:
    """The single replay actor. `snapshot_path`: where `snapshot()` writes and `__init__` restores from."""

    def __init__(self, config: Any, snapshot_path: str | None = None, seed: int = 0):
        self.config = cfg = actor_setup(config, uses_torch=False)
        self.incarnation, self.snapshot_path = new_incarnation(), snapshot_path
        self.layout = agent_layout(cfg, make_batched_env(cfg, num_envs=1))
        self.replay = build_replay(cfg, self.layout)
        self.schedule = build_schedule(cfg)
        self.pacing = ReplayPacing(cfg)
        k, cap = cfg.teachers.num_folds, cfg.replay.capacity
        self.difficulty = DifficultyTable(cap, len(self.layout.teacher_agents), k)
        self.curiosity_stamps = ScoreStamps(cap, 1)
        self.seen: dict[str, int] = {}  # "writer:incarnation" -> last seq accepted
        self.counters = {"inserts": 0, "samples": 0, "updates": 0, "episodes": 0, "icm_steps": 0,
                         "icm_scores": 0, "chunks": 0}
        self.teacher_steps, self.teacher_scores = [0] * k, [0] * k
        self.rejected: dict[str, int] = {}
        seeds = np.random.SeedSequence([int(seed), 7]).spawn(self.layout.num_agents + 1)
        self.sampler_rngs = [np.random.default_rng(s) for s in seeds[:-1]]
        self.rng = np.random.default_rng(seeds[-1])
        self.dirty, self.inserts_at_recompute = True, -1
        self.losses: dict[str, Any] = {}
        self.resumed = bool(snapshot_path and os.path.exists(snapshot_path))
        if self.resumed:
            self.restore(snapshot_path)

    # ------------------------------------------------------------------ pacing
    def status(self) -> dict[str, Any]:
        """How much work each role may be given now (`ReplayPacing.status`), and the counters the supervisor shows."""
        ready = self.replay.size >= self.replay.min_size
        return {**self.pacing.status(ready, self.replay.storage.fold_counts()),
                "size": self.replay.size, "env_steps": self.counters["inserts"],
                "episodes": self.counters["episodes"], "updates": self.counters["updates"],
                "lambda": self.schedule.lam, "incarnation": self.incarnation}

    def _reject(self, reason: str, detail: str) -> dict[str, Any]:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1
        return {"accepted": 0, "error": f"{reason}: {detail}", **self.status()}

    # ------------------------------------------------------------------ rollout -> replay
    def insert(self, chunk: Any) -> dict[str, Any]:
        """Store one rollout Chunk (B whole episodes); duplicates and bad chunks are refused, nothing stored."""
        try:
            layout = self.layout
            chunk = codec.check_chunk(chunk, n_agents=layout.num_agents, obs_dim=layout.obs_dim,
                                      act_dim=layout.act_dim)
        except codec.CodecError as err:
            return self._reject("bad_chunk", str(err))
        key, seq = chunk.writer_key, int(chunk.seq)
        if seq <= self.seen.get(key, -1):
            return self._reject("duplicate", f"{key} seq {seq} already accepted")
        try:
            self.replay.add(chunk.obs, chunk.act, chunk.rew, chunk.next_obs, chunk.done,
                            self.counters["episodes"] + chunk.env_index, int(chunk.policy_version))
        except (ValueError, TypeError) as err:
            return self._reject("invalid", str(err))
        n = chunk.rows
        self.seen[key] = seq
        self.counters["inserts"] += n
        self.counters["episodes"] += chunk.worlds
        self.counters["chunks"] += 1
        self.pacing.record_insert(n)
        self.schedule.advance(n)
        self.dirty = True
        return {"accepted": n, **self.status()}

    # ------------------------------------------------------------------ replay -> learner
    def _maybe_recompute(self) -> None:
        """Bulk priority recompute when λ or scores changed, at most every `recompute_every` inserts."""
        if not uses_curriculum(self.layout.modes):
            return
        every = self.config.service.recompute_every or self.config.env.num_envs * self.config.env.episode_length
        due = self.counters["inserts"] - self.inserts_at_recompute >= every
        if self.replay.lam is None or (self.dirty and due) or self.replay.lam != self.schedule.lam and due:
            self.replay.recompute_priorities(self.schedule.lam)
            self.dirty, self.inserts_at_recompute = False, self.counters["inserts"]

    def sample(self, n: int) -> tuple[Any, dict[str, Any]]:
        """Up to n per-owner minibatches (a LearnerBatch of [n, N, S] arrays), as many as the rate limiters allow
        (None if none)."""
        n = min(int(n), self.status()["allowed_updates"])
        if n < 1:
            return None, self.status()
        self._maybe_recompute()
        beta = beta_is(self.config, self.counters["inserts"])
        betas = [beta if w else 0.0 for w in self.layout.importance_weights]
        batch = buffer.sample_owner_batches(self.replay, n, self.config.maddpg.batch_size, self.sampler_rngs, betas)
        self.pacing.record_updates(n)
        self.counters["updates"] += n
        self.counters["samples"] += int(batch.slots.size)
        return batch, self.status()

    def learner_result(self, result: Any) -> dict[str, Any]:
        """PER / ACL-td_self feedback: |δ| for the sampled (slot, generation) pairs; stale ones are dropped."""
        if result is None:
            return self.status()
        try:
            feedback = check_feedback(result, self.layout.num_agents)
        except MessageError as err:
            return self._reject("bad_feedback", str(err))
        stale, scores_changed = buffer.apply_learner_feedback(self.replay, self.layout, feedback)
        self._count_stale(stale)
        self.dirty = self.dirty or scores_changed
        return self.status()

    def _count_stale(self, n: int) -> None:
        if n > 0:
            self.rejected["stale"] = self.rejected.get("stale", 0) + int(n)

    # ------------------------------------------------------------------ replay -> teachers / ICM
    def teacher_work(self, folds: list[int], steps: int) -> tuple[TeacherWork | None, dict[str, Any]]:
        """For the teacher actor hosting `folds`: fit rows [steps, 1, F, S] drawn from each fold only, and the
        rows (of other folds) whose score from these teachers is oldest, to score."""
        cfg = self.config
        if not self.pacing.teachers or self.replay.size < self.replay.min_size:
            return None, self.status()
        folds = [int(f) for f in folds]
        steps = min(int(steps), *(self.pacing.teachers[f].allowed_samples() for f in folds))
        if steps < 1 or (self.replay.storage.fold_counts()[folds] == 0).any():
            return None, self.status()
        fit = buffer.fold_batch_slots(self.replay, folds, cfg.teachers.batch_size, self.rng, steps=steps)
        valid = self.replay.valid_slots()
        age = self.difficulty.stamps(valid, self.replay.generations(valid))[:, folds].astype(np.float64)  # [M, F]
        age[self.replay.storage.fold[valid][:, None] == np.asarray(folds)[None, :]] = np.inf  # own fold: never
        key = age.min(1)
        useful = np.isfinite(key)
        score = buffer.oldest_slots(valid[useful], key[useful], cfg.service.score_rows_per_call)
        for f in folds:
            self.pacing.teachers[f].record_sample(steps)
            self.teacher_steps[f] += steps
        return TeacherWork(tuple(folds), buffer.rows_at(self.replay, fit), fit, buffer.score_rows(self.replay, score),
                           self.counters["updates"]), self.status()

    def write_teacher_scores(self, scores: Any) -> dict[str, Any]:
        """Errors e[M, A_t, F] of the teachers of `folds` -> c of the rows (eq. 11 over the blind teachers)."""
        if scores is None:
            return self.status()
        try:
            msg = check_teacher_scores(scores, len(self.layout.teacher_agents), self.config.teachers.num_folds)
        except MessageError as err:
            return self._reject("bad_scores", str(err))
        fresh = self.replay.storage.fresh_mask(msg.slots, msg.generations)
        row_fold = self.replay.storage.fold[msg.slots[fresh]]
        _, stale = buffer.write_difficulty(self.replay, self.difficulty, self.layout.teacher_agents, msg.slots,
                                           msg.generations, msg.folds, msg.errors, msg.updates)
        self._count_stale(stale)
        for f in msg.folds:
            self.teacher_scores[f] += int((row_fold != f).sum())
            self.losses[f"teacher_{f}"] = float(msg.loss)
        self.dirty = True
        return self.status()

    def icm_work(self, steps: int) -> tuple[CuriosityWork | None, dict[str, Any]]:
        """Uniform fit rows [steps, S] and the rows with the oldest curiosity score."""
        cfg = self.config
        if self.pacing.icm is None or self.replay.size < self.replay.min_size:
            return None, self.status()
        steps = min(int(steps), self.pacing.icm.allowed_samples())
        if steps < 1:
            return None, self.status()
        fit = buffer.uniform_slots(self.replay, (steps, cfg.icm.batch_size), self.rng)
        valid = self.replay.valid_slots()
        stamps = self.curiosity_stamps.stamps(valid, self.replay.generations(valid))[:, 0]
        score = buffer.oldest_slots(valid, stamps, cfg.service.score_rows_per_call)
        self.pacing.icm.record_sample(steps)
        self.counters["icm_steps"] += steps
        return CuriosityWork(buffer.rows_at(self.replay, fit, ("obs", "act", "next_obs")),
                             buffer.score_rows(self.replay, score), self.counters["updates"]), self.status()

    def write_curiosity(self, scores: Any) -> dict[str, Any]:
        """ρ[M, A_c] (eq. 18) for (slot, generation) pairs from the ICM actor."""
        if scores is None:
            return self.status()
        try:
            msg = check_curiosity_scores(scores, len(self.layout.icm_agents))
        except MessageError as err:
            return self._reject("bad_scores", str(err))
        fresh = self.replay.storage.fresh_mask(msg.slots, msg.generations)
        accepted, stale = buffer.write_curiosity(self.replay, self.layout.icm_agents, msg.slots, msg.generations,
                                                 msg.rho)
        self._count_stale(stale)
        self.curiosity_stamps.mark(msg.slots[fresh], msg.generations[fresh], 0, msg.updates)
        self.counters["icm_scores"] += accepted
        self.losses["icm"] = float(msg.loss)
        self.dirty = True
        return self.status()

    # ------------------------------------------------------------------ observability and state
    def report(self) -> Report:
        """Metrics report: buffer, λ, difficulty / priority distributions, score age and coverage."""
        replay: dict[str, Any] = {"size": self.replay.size, "capacity": self.replay.capacity,
                                  "inserts": self.counters["inserts"], "samples": self.counters["samples"],
                                  "rejected": dict(self.rejected)}
        size = self.replay.size
        if size and uses_curriculum(self.layout.modes):
            d = self.replay.recompute_priorities(self.schedule.lam, details=True)
            self.dirty, self.inserts_at_recompute = False, self.counters["inserts"]
            pick = self.rng.integers(0, size, min(size, REPORT_SAMPLES))
            scored = d["scored"][pick]
            replay.update(difficulty=d["c_hat"][pick][scored], priority=d["priority"][pick],
                          kfold_priority=d["kp"][pick][scored], curiosity_priority=d["cp"][pick])
        if self.pacing.teachers and size:
            valid = self.replay.valid_slots()
            times = self.difficulty.stamps(valid, self.replay.generations(valid))
            replay["score_coverage"] = float(self.replay.storage.scored["difficulty"][:size][
                :, self.layout.teacher_agents].all(1).mean())
            ages = self.counters["updates"] - times[times >= 0]
            if ages.size:
                replay["score_age"] = ages[self.rng.integers(0, ages.size, min(ages.size, REPORT_SAMPLES))]
        teachers = {str(k): FitReport(steps=self.teacher_steps[k], scores=self.teacher_scores[k],
                                      loss=self.losses.get(f"teacher_{k}"))
                    for k in range(len(self.pacing.teachers))} if self.pacing.teachers else None
        icm = FitReport(steps=self.counters["icm_steps"], scores=self.counters["icm_scores"],
                        loss=self.losses.get("icm")) if self.pacing.icm is not None else None
        return Report(source="replay", role="replay", incarnation=self.incarnation, resumed=self.resumed,
                      replay=ReplayReport(**replay), curriculum=CurriculumReport(lam=self.schedule.lam),
                      teachers=teachers, icm=icm)

    def state_dict(self) -> dict[str, Any]:
        """Codec-ready state: the buffer, score tables, dedupe table, counters, limiters and λ's step count."""
        return {"replay": self.replay.state_dict(), "difficulty": self.difficulty.state_dict(),
                "curiosity_stamps": self.curiosity_stamps.state_dict(),
                "seen": dict(self.seen), "counters": dict(self.counters), "rejected": dict(self.rejected),
                "teacher_steps": list(self.teacher_steps), "teacher_scores": list(self.teacher_scores),
                **self.pacing.state_dict(),
                "schedule_env_steps": self.schedule.env_steps}

    def snapshot(self, path: str | None = None) -> int:
        """Write the state atomically (msgpack, no pickle) to `path` or the snapshot path; returns bytes."""
        target = path or self.snapshot_path
        if target is None:
            raise ValueError("snapshot needs a path: none given and no snapshot_path configured")
        Path(target).parent.mkdir(parents=True, exist_ok=True)
        return codec.write_snapshot_atomic(target, self.state_dict())

    def restore(self, path: str) -> None:
        """Load a snapshot written by `snapshot` (validated by the codec and the buffer before use)."""
        state = codec.read_snapshot(path, limits=codec.SNAPSHOT_LIMITS)
        self.replay.load_state_dict(state["replay"])
        self.difficulty.load_state_dict(state["difficulty"])
        self.curiosity_stamps.load_state_dict(state["curiosity_stamps"])
        self.seen = {str(k): int(v) for k, v in state["seen"].items()}
        self.counters.update({k: int(v) for k, v in state["counters"].items()})
        self.rejected = {str(k): int(v) for k, v in state["rejected"].items()}
        self.teacher_steps = [int(v) for v in state["teacher_steps"]]
        self.teacher_scores = [int(v) for v in state["teacher_scores"]]
        self.pacing.load_state_dict(state)
        self.schedule.env_steps = int(state["schedule_env_steps"])
        self.dirty = True

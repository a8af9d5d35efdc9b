"""Replay server: owns the buffer, folds, score columns, λ, every sampler and the rate limiters.

Where it sits: the hub of the flow, and a shell: dedupe, pacing and status around the replay side of Algorithm 1's
steps (`cmcl.replay.buffer_steps`) and its scoring state (`cmcl.scorers.scoring.ScoringState`: stamps, teacher
errors, insertion times and the rule that picks the rows to rescore), the same on both schedulers. Rollout
`Chunk`s come in (`insert`, validated by `cmcl.io.records.check_chunk`, idempotent by writer / incarnation / seq);
every scorer (a teacher group, the ICM, the online critics the learner hosts) gets its `ScoreWork` from one `work`
and sends its `Scores` back to one `write`, keyed by (slot, generation), stale ones dropped; the learner receives
prioritized `LearnerBatch`es (`sample`) and returns |δ| (`learner_result`). Under ACL td_self no update is handed
out while a row is unscored by the online critics (`status`; ALGORITHM.md A11: score at insertion). Priorities are
recomputed in bulk when λ or scores changed, at most every `service.recompute_every` inserts. λ advances with the
env steps accepted here.

Distributed deviation from §3.8 (ALGORITHM.md §3.9), measured by `cmcl_teacher_score_age_updates`: teacher k
scores rows of the other folds asynchronously; c_j is (K−1)·mean over the blind teachers that have scored j so
far (`cmcl.scorers.difficulty.DifficultyTable`); a row no teacher has scored yet samples at the
provisional priority (`cmcl.replay.priority.provisional_priority`; ε_p while no row is scored).
Every method returns (or ends with) a `ReplayStatus` the supervisor uses to pace its calls.
"""

from __future__ import annotations

import dataclasses
import sys
from typing import Any

import numpy as np

from cmcl.io import codec, records
from cmcl.io.durable import ReplayStore, StoreError
from cmcl.replay import buffer_steps
from cmcl.replay.curriculum import unplayed_steps
from cmcl.replay.dedupe import InsertLedger
from cmcl.replay.messages import (
    CURIOSITY,
    CURIOSITY_KEY,
    DIFFICULTY,
    ONLINE_TD,
    ROW_KEYS,
    MessageError,
    ReplayStatus,
    Scorer,
    Scores,
    ScoreWork,
    check_feedback,
    check_scores,
)
from cmcl.replay.pacing import pacing_from_config
from cmcl.replay.snapshot import OlderRunError, older_run, rng_state, set_rng_state
from cmcl.scorers.scoring import ScoringState
from cmcl.system import beta_is, build_replay, build_schedule, layout_of
from services.observability.replay_report import REPORT_SAMPLES, ReplayTallies, replay_report
from services.observability.report_schema import Report
from services.runtime.common import actor_setup, new_incarnation

ONLINE_CRITICS = Scorer(ONLINE_TD)  # the scorer the learner hosts (ACL td_self)
# the top-level keys of `ReplayServer.state_dict`, each one required in a snapshot read back
SNAPSHOT_KEYS = ("replay", "difficulty", "curiosity_stamps", "online_td_stamps", "inserted_at", "ledger", "counters",
                 "rejected", "stale_scores", "teacher_steps", "teacher_scores", "learner_limit", "teacher_limits",
                 "icm_limit", "schedule_env_steps", "sampler_rngs", "rng")


class ReplayServer:
    """The single replay actor. `store_dir`: its durable store (`cmcl.io.durable.ReplayStore`), which `snapshot()`
    and every insert write and `__init__` restores from."""

    def __init__(self, config: Any, store_dir: str | None = None, seed: int = 0):
        self.config = cfg = actor_setup(config, uses_torch=False)
        self.incarnation = new_incarnation()
        self.store = ReplayStore(store_dir, fsync=cfg.service.replay_log_fsync) if store_dir else None
        self.layout = layout_of(cfg)
        self.replay = build_replay(cfg, self.layout)
        self.schedule = build_schedule(cfg)
        self.pacing = pacing_from_config(cfg, asynchronous=True)  # the rate limits, with the service's slack
        k, cap = cfg.teachers.num_folds, cfg.replay.capacity
        self.scoring = ScoringState.for_layout(self.layout, cap, k)  # score stamps, teacher errors, insertion times
        # the agents A of each score column a scorer of this run writes (`write` checks Scores against them)
        self.score_widths = {c: int(n) for c, n in ((DIFFICULTY, self.layout.teacher_agents.size),
                                                    (CURIOSITY, self.layout.icm_agents.size),
                                                    (ONLINE_TD, self.layout.num_agents * self.scoring.online_td))
                             if n}
        self.ledger = InsertLedger()  # which (writer:incarnation, seq) chunks are stored
        self.logged_rows = 0  # transitions in the durable log since the last snapshot
        self.counters = {"inserts": 0, "samples": 0, "updates": 0, "episodes": 0, "icm_steps": 0,
                         "icm_scores": 0, "chunks": 0, "restored_records": 0}
        self.teacher_steps, self.teacher_scores = [0] * k, [0] * k
        self.fold_groups: dict[int, tuple[int, ...]] = {}  # fold -> the folds of the teacher serving it (status)
        # refused inputs per reason (services.observability.report_schema.REJECT_REASONS)
        self.rejected: dict[str, int] = {}
        self.stale_scores = 0  # score / |δ| updates dropped as stale (expected, not refused input)
        seeds = np.random.SeedSequence([int(seed), 7]).spawn(self.layout.num_agents + 1)
        self.sampler_rngs = [np.random.default_rng(s) for s in seeds[:-1]]
        self.rng = np.random.default_rng(seeds[-1])
        # the reports' subsamples: a stream of their own, so that when reports are asked (wall clock) never moves
        # the draws of the fit rows and the sampling
        self.report_rng = np.random.default_rng([int(seed), 8])
        self.dirty, self.inserts_at_recompute = True, -1
        self.losses: dict[str, Any] = {}
        self.resumed = self.store is not None and self.store.exists()
        if self.resumed:
            self.restore()
        elif cfg.run.carry_replay and cfg.run.init_from:  # a new run starting with the rows of the run before
            self._carry_replay(cfg.run.init_from)

    def _carry_replay(self, init_from: str) -> None:
        """Add init_from's replay rows, padded to this run's agents (cmcl.run.carried_replay), then snapshot them, so
        that a restart of this actor restores them rather than carrying them again."""
        from cmcl.run.carried_replay import carry_replay_rows

        self.scoring.inserted(carry_replay_rows(self.replay, init_from, self.layout.entities), 0)
        self.dirty = True
        if self.store is not None:
            self.snapshot()

    # ------------------------------------------------------------------ pacing
    def status(self) -> ReplayStatus:
        """How much work each role may be given now (`cmcl.replay.pacing.Pacing.status`), and the counters the
        supervisor shows."""
        counts = self.replay.storage.fold_counts()
        # a fold served with others (one stacked teacher: teacher_work) gets no work while one of them holds no row
        # (fewer episodes than folds): its fit steps are not owed yet, else the run's end waits for them forever
        counts[[f for f, group in self.fold_groups.items() if (counts[list(group)] == 0).any()]] = 0
        pacing = dataclasses.asdict(self.pacing.status(counts))
        if self.scoring.online_td and pacing["allowed_updates"] and self.scoring.unscored(self.replay, online_td=True):
            # ACL td_self: a row is scored by the online critics before it can be sampled (ALGORITHM.md A11: score
            # at insertion; the supervisor has them score every chunk it inserts): no update until they have
            pacing.update(allowed_updates=0, updates_held_by="scores")
        return ReplayStatus(**pacing, size=self.replay.size, env_steps=self.counters["inserts"],
                            episodes=self.counters["episodes"], updates=self.counters["updates"],
                            lam=self.schedule.lam, incarnation=self.incarnation)

    def _reject(self, reason: str, detail: str) -> ReplayStatus:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1
        return dataclasses.replace(self.status(), accepted=0, error=f"{reason}: {detail}")

    # ------------------------------------------------------------------ rollout -> replay
    def insert(self, chunk: Any) -> ReplayStatus:
        """Store one rollout Chunk (B whole episodes) exactly once, whatever order chunks arrive in; bad chunks are
        refused and nothing is stored. An accepted chunk is in the durable log before this returns."""
        try:
            layout = self.layout
            chunk = records.check_chunk(chunk, n_agents=layout.num_agents, obs_dim=layout.obs_dim,
                                      act_dim=layout.act_dim, num_worlds=self.config.env.num_envs)
        except codec.CodecError as err:
            return self._reject("bad_chunk", str(err))
        if self.ledger.seen(chunk.writer_key, chunk.seq):
            return self._reject("duplicate", f"{chunk.writer_key} seq {chunk.seq} already stored")
        try:
            self._store(chunk)
        except (ValueError, TypeError) as err:
            return self._reject("invalid", str(err))
        if self.store is not None:
            self.store.append(records.encode_chunk(chunk), chunk.rows)
            self.logged_rows += chunk.rows
            if self.logged_rows >= self.replay.capacity:  # the log never holds more than one buffer's worth
                self.snapshot()
        return dataclasses.replace(self.status(), accepted=chunk.rows)

    def _event(self, name: str, count: int, folds: list[int] | tuple[int, ...] = ()) -> None:
        """Apply work handed out (learner updates, teacher / ICM fit steps) and log it, so that a restarted server's
        counters and limits never go back."""
        self._apply_event({"name": name, "count": int(count), "folds": list(folds)})
        if self.store is not None:
            self.store.append(records.encode_event(name, count, folds))

    def _apply_event(self, event: dict[str, Any]) -> None:
        """Counters and limiters after an event of `_event` (also log replay)."""
        n = int(event["count"])
        if event["name"] == "updates":
            self.pacing.record_updates(n)
            self.counters["updates"] += n
            self.counters["samples"] += n * self.layout.num_agents * self.config.maddpg.batch_size
        elif event["name"] == "teacher_steps":
            self.pacing.record_teacher_steps(event["folds"], n)
            for f in event["folds"]:
                self.teacher_steps[f] += n
        else:
            self.pacing.record_icm_steps(n)
            self.counters["icm_steps"] += n

    def _store(self, chunk: Any) -> None:
        """Add a valid, new chunk to the buffer and advance the counters, the limiters and λ (also log replay)."""
        slots = self.replay.add(chunk.obs, chunk.act, chunk.rew, chunk.next_obs, chunk.done,
                                self.counters["episodes"] + chunk.env_index, int(chunk.policy_version))
        self.scoring.inserted(slots, self.counters["updates"])
        self.ledger.accept(chunk.writer_key, chunk.seq)
        n = chunk.rows
        self.counters["inserts"] += n
        self.counters["episodes"] += chunk.worlds
        self.counters["chunks"] += 1
        self.pacing.record_insert(n)
        # whole episodes: λ's clock counts each one as env.episode_length steps, however long it was
        self.schedule.advance(n + unplayed_steps(np.bincount(chunk.env_index), self.config.env.episode_length))
        self.dirty = True

    # ------------------------------------------------------------------ replay -> learner
    def _maybe_recompute(self) -> None:
        """Bulk priority recompute when λ or scores changed, at most every `recompute_every` inserts."""
        if not self.replay.recomputes:
            return
        every = self.config.service.recompute_every or self.config.env.num_envs * self.config.env.episode_length
        due = self.counters["inserts"] - self.inserts_at_recompute >= every
        if self.replay.lam is None or (self.dirty and due) or self.replay.lam != self.schedule.lam and due:
            self.replay.recompute_priorities(self.schedule.lam)
            self.dirty, self.inserts_at_recompute = False, self.counters["inserts"]

    def sample(self, n: int) -> tuple[Any, ReplayStatus]:
        """Up to n per-owner minibatches (a LearnerBatch of [n, N, S] arrays), as many as the rate limiters allow
        (None if none)."""
        n = min(int(n), self.status().allowed_updates)
        if n < 1:
            return None, self.status()
        self._maybe_recompute()
        beta = beta_is(self.config, self.counters["inserts"])
        betas = [beta if w else 0.0 for w in self.layout.importance_weights]
        batch = buffer_steps.sample_owner_batches(self.replay, n, self.config.maddpg.batch_size, self.sampler_rngs,
                                                  betas, self.layout.candidates, self.layout.uniform_actor,
                                                  self.layout.permuted_select)
        self.scoring.sampled(batch.slots, self.counters["updates"], self.rng, REPORT_SAMPLES)
        if self.config.icm.intrinsic_reward_coef > 0:  # each row's ρ as the ICM scorer last wrote it (0 before)
            batch.rows[CURIOSITY_KEY] = self.replay.storage.scores["curiosity"][batch.slots]
        self._event("updates", n)
        if self.scoring.online_td:  # the online critics the learner hosts rescore the oldest of their scores after
            # this call's updates (every row was scored before it could be sampled: `status`)
            batch = dataclasses.replace(batch, score=self.work(ONLINE_CRITICS, 0)[0])
        return batch, self.status()

    def learner_result(self, result: Any) -> ReplayStatus:
        """The learner's per-row losses of the sampled (slot, generation) pairs, to the samplers that ask for them
        (PER, ReLo, ACL td_self, ...); stale ones are dropped."""
        if result is None:
            return self.status()
        try:
            feedback = check_feedback(result, self.layout.num_agents)
            if feedback.scores is not None:
                check_scores(feedback.scores, {ONLINE_TD: self.layout.num_agents}, self.config.teachers.num_folds)
        except MessageError as err:
            return self._reject("bad_feedback", str(err))
        stale, scores_changed = buffer_steps.apply_learner_feedback(self.replay, self.layout, feedback)
        self._count_stale(stale)
        self.dirty = self.dirty or scores_changed
        if feedback.scores is not None:  # the online critics' scores (ACL td_self), the scorer the learner hosts
            self._write(feedback.scores)
        return self.status()

    def _count_stale(self, n: int) -> None:
        """Count score / |δ| updates dropped as stale: expected by design (a row overwritten while a teacher, the
        ICM or the learner held it), so counted apart from refused input."""
        self.stale_scores += max(0, int(n))

    # ------------------------------------------------------------------ replay -> scorers -> replay
    def work(self, scorer: Scorer, steps: int) -> tuple[ScoreWork | None, ReplayStatus]:
        """A scorer's next work (None when its pacing allows no fit step yet): fit rows for up to `steps` fit steps
        and the rows whose score from it is oldest (`ScoringState.rows_to_score`), never-scored first.

        A teacher group (DIFFICULTY, scorer.folds): fit rows [steps, B, F, S] drawn from each fold only (B = 1, or
        one batch per teacher agent under teachers.fit_batch = "per_agent"), rows of other folds to score. The ICM
        (CURIOSITY): uniform fit rows [steps, S] (obs, act, next_obs). The online critics (ONLINE_TD, the learner's:
        `sample` hands their work out): no fit rows; every row they have not scored, topped up with the oldest."""
        cfg, count = self.config, self.config.service.score_rows_per_call
        if not isinstance(scorer, Scorer) or scorer.column not in self.score_widths:
            raise MessageError(f"work: scorer must be a Scorer of a column in {sorted(self.score_widths)}, got "
                               f"{scorer!r:.80}")
        if scorer.column == ONLINE_TD:
            rows = self.scoring.rows_to_score(self.replay, count, online_td=True, every_unscored=True)
            return ScoreWork(scorer, {}, None, buffer_steps.score_rows(self.replay, rows),
                             self.counters["updates"]), self.status()
        if scorer.column == DIFFICULTY:
            folds = [int(f) for f in scorer.folds]
            self.fold_groups.update((f, tuple(folds)) for f in folds)
            steps = min(int(steps), self.pacing.teacher_steps_allowed(folds))
            if steps < 1 or (self.replay.storage.fold_counts()[folds] == 0).any():
                return None, self.status()
            draws = buffer_steps.teacher_fit_draws(cfg.teachers.fit_batch, self.layout.teacher_agents)
            fit = buffer_steps.fold_batch_slots(self.replay, folds, cfg.teachers.batch_size, self.rng, draws, steps)
            rows = self.scoring.rows_to_score(self.replay, count, folds=folds)
            keys, event = ROW_KEYS, ("teacher_steps", steps, folds)
        else:
            steps = min(int(steps), self.pacing.icm_steps_allowed())
            if steps < 1:
                return None, self.status()
            fit = buffer_steps.uniform_slots(self.replay, (steps, cfg.icm.batch_size), self.rng)
            rows = self.scoring.rows_to_score(self.replay, count, curiosity=True)
            keys, event = ("obs", "act", "next_obs"), ("icm_steps", steps, ())
        self._event(*event)
        return ScoreWork(scorer, buffer_steps.rows_at(self.replay, fit, keys), fit,
                         buffer_steps.score_rows(self.replay, rows), self.counters["updates"]), self.status()

    def write(self, scores: Any) -> ReplayStatus:
        """A scorer's Scores, validated, into its score column (stale (slot, generation) pairs dropped and counted):
        teacher errors e[M, A_t, F] -> c of the rows (eq. 11 over the blind teachers), ρ[M, A_c] (eq. 18), the online
        critics' |δ|[M, N]. None (a scorer given no work) changes nothing."""
        if scores is None:
            return self.status()
        try:
            msg = check_scores(scores, self.score_widths, self.config.teachers.num_folds)
        except MessageError as err:
            return self._reject("bad_scores", str(err))
        self._write(msg)
        return self.status()

    def _write(self, msg: Scores) -> None:
        """Store a checked Scores in its column and count it (`write`, and the learner's in `learner_result`)."""
        column, s, g = msg.scorer.column, msg.slots, msg.generations
        if column == DIFFICULTY:
            row_fold = self.replay.storage.fold[s[self.replay.storage.fresh_mask(s, g)]]
            _, stale = self.scoring.write_difficulty(self.replay, s, g, msg.scorer.folds, msg.values, msg.stamp)
            for f in msg.scorer.folds:
                self.teacher_scores[f] += int((row_fold != f).sum())
                self.losses[f"teacher_{f}"] = float(msg.loss)
        elif column == CURIOSITY:
            accepted, stale = self.scoring.write_curiosity(self.replay, s, g, msg.values, msg.stamp)
            self.counters["icm_scores"] += accepted
            self.losses["icm"] = float(msg.loss)
        else:
            _, stale = self.scoring.write_online_td(self.replay, s, g, msg.values, msg.stamp)
        self._count_stale(stale)
        self.dirty = True

    # ------------------------------------------------------------------ observability and state
    def report(self) -> Report:
        """Metrics report: buffer, λ, difficulty / priority distributions, score age and coverage."""
        details = None
        if self.replay.size and self.replay.curriculum:  # the curriculum's terms at the current λ, read-only: a
            # report (asked every few seconds of wall clock) never changes what the run samples
            details = self.replay.recompute_priorities(self.schedule.lam, details=True, apply=False)
        c = self.counters
        tallies = ReplayTallies(inserts=c["inserts"], samples=c["samples"], rejected=self.rejected,
                                stale_scores=self.stale_scores, teacher_steps=tuple(self.teacher_steps),
                                teacher_scores=tuple(self.teacher_scores), icm_steps=c["icm_steps"],
                                icm_scores=c["icm_scores"], losses=self.losses)
        return replay_report(self.replay, self.scoring, tallies, lam=self.schedule.lam, updates=c["updates"],
                             details=details, rng=self.report_rng, incarnation=self.incarnation,
                             resumed=self.resumed)

    def state_dict(self) -> dict[str, Any]:
        """Codec-ready state: the buffer, score tables, insert ledger, counters, limiters, λ's step count and the
        generators (each agent's sampler stream and the server's own: a restored server continues their draws
        instead of repeating the first incarnation's)."""
        return {"replay": self.replay.state_dict(), **self.scoring.state_dict(),
                "ledger": self.ledger.state_dict(), "counters": dict(self.counters), "rejected": dict(self.rejected),
                "stale_scores": self.stale_scores, "teacher_steps": list(self.teacher_steps),
                "teacher_scores": list(self.teacher_scores),
                **self.pacing.state_dict(),
                "schedule_env_steps": self.schedule.env_steps,
                "sampler_rngs": [rng_state(g) for g in self.sampler_rngs], "rng": rng_state(self.rng)}

    def snapshot(self) -> int:
        """Write the state as a new snapshot generation of the store (msgpack, no pickle; the log restarts empty);
        returns bytes written."""
        if self.store is None:
            raise ValueError("snapshot needs a store: this replay server was created without store_dir")
        self.logged_rows = 0
        return self.store.snapshot(self.state_dict())

    def restore(self) -> None:
        """Load the store's snapshot (checked against its manifest), then replay the chunks logged since it that
        verify; a damaged log (moved aside by the store) is counted and said on stderr, with what was lost."""
        state, frames, damage = self.store.load()
        if state is not None:
            try:
                self._load_state(state)
            except OlderRunError as err:  # refused as a snapshot that fails its checks is (services.launch)
                raise StoreError(str(err)) from None
        for payload in frames:  # in the order they were applied
            record = records.decode_log_record(payload)
            if isinstance(record, dict):
                self._apply_event(record)
            else:
                self.logged_rows += record.rows
                if not self.ledger.seen(record.writer_key, record.seq):
                    self._store(record)
        self.counters["restored_records"] = len(frames)
        if damage is not None:  # counted under the label it always had; the line says what was lost and where
            self.rejected["log_truncated"] = self.rejected.get("log_truncated", 0) + 1
            print(f"replay log: {damage}", file=sys.stderr)

    def _load_state(self, state: dict[str, Any]) -> None:
        """Apply a `state_dict()` (each part validated by its owner before use; a snapshot without a part this
        version writes is refused in one line, `cmcl.replay.snapshot.older_run`)."""
        missing = [key for key in SNAPSHOT_KEYS if key not in state]
        if missing:
            raise OlderRunError(older_run(f"replay server snapshot without {missing[0]!r}"))
        self.replay.load_state_dict(state["replay"])
        self.scoring.load_state_dict(state)
        self.ledger.load_state_dict(state["ledger"])
        self.counters.update({k: int(v) for k, v in state["counters"].items()})
        self.rejected = {str(k): int(v) for k, v in state["rejected"].items()}
        self.stale_scores = int(state["stale_scores"])
        self.teacher_steps = [int(v) for v in state["teacher_steps"]]
        self.teacher_scores = [int(v) for v in state["teacher_scores"]]
        self.pacing.load_state_dict(state)
        self.schedule.env_steps = int(state["schedule_env_steps"])
        if len(state["sampler_rngs"]) != len(self.sampler_rngs):
            raise ValueError(f"sampler_rngs: the snapshot holds {len(state['sampler_rngs'])} agents' generators, "
                             f"this run has {len(self.sampler_rngs)} agents")
        for agent, (g, saved) in enumerate(zip(self.sampler_rngs, state["sampler_rngs"], strict=True)):
            set_rng_state(g, saved, f"sampler_rngs[{agent}]")
        set_rng_state(self.rng, state["rng"], "rng")
        self.dirty = True

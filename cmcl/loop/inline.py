"""The synchronous CMCL training loop (Algorithm 1, ALGORITHM.md §3.8), inline in one process without Ray.

Where it sits: the reference implementation and the baseline the distributed service is measured against.
It runs the same classes the service runs (built by cmcl.system) through the same step functions
(cmcl.replay.buffer_steps for the buffer side, cmcl.learners.network_steps for the networks):
rollout of B batched worlds -> replay -> per update (when due by `cmcl.replay.pacing.Pacing`, the service's pacing
in its synchronous form: one per `maddpg.update_every` world steps once warm): the teacher and ICM steps due,
scoring of the new rows plus the oldest scores up to `teachers.rescore_rows_per_update` rows (the rule of
`cmcl.replay.scoring.ScoringState`, the service's too), priority recompute at the current λ, one MADDPG update of
all agents; λ advanced per world step. What its checkpoint holds is cmcl/loop/checkpoint.py; the metrics rows it
logs, cmcl/loop/metrics_rows.py.
Command line: `python -m cmcl train --runner inline` (cmcl/loop/__main__.py; alias `python -m cmcl.loop`).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from cmcl.config import Config
from cmcl.episodes import WorldEpisodes
from cmcl.io.rundir import RunDirectory
from cmcl.learners import network_steps
from cmcl.learners.assignment import STATS as ASSIGNMENT_STATS
from cmcl.learning_progress import LearningProgress, agent_mean
from cmcl.loop.checkpoint import load_loop_state, loop_state, restore_loop, save_loop_checkpoint
from cmcl.loop.metrics_rows import finished_episode_rows, format_progress, progress_row
from cmcl.messages import LearnerFeedback, Rows
from cmcl.progress import TrainingDiverged, solved
from cmcl.replay import buffer_steps
from cmcl.replay.curriculum import unplayed_steps
from cmcl.replay.pacing import pacing_from_config
from cmcl.replay.scoring import ScoringState
from cmcl.run_clock import RunClock
from cmcl.system import (
    agent_layout,
    beta_is,
    build_icm,
    build_maddpg,
    build_replay,
    build_schedule,
    build_teachers,
    make_batched_env,
    to_env_actions,
)

RESCORE_CHUNK = 2048  # rows per scoring pass (bounds memory of the A×K teacher forward)
RNG_NAMES = ("env", "noise", "teacher", "icm")  # the loop's generators, checkpointed by name
SAMPLER_SEED = 4  # seed stream of the learner's per-agent sampling generators (`sampler_rngs`), spawned from it
TORCH_SEEDS = slice(5, 8)  # seed streams of MADDPG, the teachers and the ICM


class InlineLoop:
    """Algorithm 1 over B lock-stepped worlds. Construct, then `run()`; `state_dict()` is the checkpoint."""

    def __init__(self, config: Config, run_dir: RunDirectory | None = None,
                 progress: Callable[[str], None] | None = print):
        torch.set_num_threads(1)
        self.config, self.run_dir, self.progress = config, run_dir, progress
        seeds = np.random.SeedSequence(config.run.seed).spawn(TORCH_SEEDS.stop)
        self.rng = {name: np.random.default_rng(s) for name, s in zip(RNG_NAMES, seeds, strict=False)}
        torch_seeds = [int(s.generate_state(1)[0]) for s in seeds[TORCH_SEEDS]]
        self.env = make_batched_env(config, seed=self.rng["env"], auto_reset=True)
        self.layout = agent_layout(config, self.env)
        self.sampler_rngs = [np.random.default_rng(s) for s in seeds[SAMPLER_SEED].spawn(self.layout.num_agents)]
        self.maddpg = build_maddpg(config, self.layout, torch_seeds[0])
        self.replay = build_replay(config, self.layout)
        self.teachers = build_teachers(config, self.layout, torch_seeds[1])
        self.icm = build_icm(config, self.layout, torch_seeds[2])
        self.scoring = ScoringState.for_layout(self.layout, config.replay.capacity, config.teachers.num_folds)
        self.schedule = build_schedule(config)
        self.prioritized = self.replay.recomputes  # some agent's sampler rebuilds its priorities each update
        # LaBER: the reward-bearing share of the rows its agents picked since the last progress row
        self.agents = np.arange(self.layout.num_agents)
        self.picked_rewarded, self.picked_count = np.zeros(self.layout.num_agents), 0
        self.pacing = pacing_from_config(config)  # what is due: updates per env step, fit steps per update
        self.learning_progress = LearningProgress.from_run_config(config.run)  # run.stop_progress
        self.counters = {"episodes": 0, "env_steps": 0, "updates": 0, "rounds": 0}
        self.elapsed_s = 0.0  # training wall clock so far, seconds (kept across checkpoint + resume)
        self.segment_s = 0.0  # this command's training seconds (run.max_seconds is this command's budget)
        self.window: deque[dict[str, Any]] = deque(maxlen=config.run.smoothing_window)
        self.last_stats: dict[str, Any] = {}
        self.stopped = False  # the last `run` ended because its `stop` said so
        self.obs = self.env.reset()
        self.episodes = WorldEpisodes(self.env.num_envs)  # the episode id of each world's row (folds by episode)

    # ------------------------------------------------------------------ one batched env step
    def env_step(self) -> list[dict[str, Any]]:
        """Act in all B worlds, store the B new transitions, run the updates that are due (which score them).

        Returns the episode rows of worlds whose episode ended in this step.
        """
        cfg, b = self.config, self.env.num_envs
        actions = self.maddpg.act(self.obs, cfg.maddpg.exploration_std, rng=self.rng["noise"])  # [B, N, act]
        if not np.isfinite(actions).all():
            raise TrainingDiverged(self.config, self.counters["episodes"], self.counters["updates"])
        next_obs, rew, _, info = self.env.step(to_env_actions(actions, cfg.maddpg.discrete))
        slots = self.replay.add(self.obs, actions, rew, info["final_obs"], info["terminated"].astype(np.float32),
                                self.episodes.ids, policy_version=self.maddpg.updates)
        self.scoring.inserted(slots, self.counters["updates"])
        self.episodes.advance(info["episode_mask"])
        self.obs = next_obs
        self._run_due_updates(b)
        if "length" in info["episode"]:  # env.factory worlds: λ's clock counts every episode as episode_length steps
            self.schedule.advance(unplayed_steps(info["episode"]["length"], cfg.env.episode_length))
        rows = finished_episode_rows(self, info) if info["episode_mask"].any() else []
        if rows:
            self.counters["rounds"] += 1
        for row in rows:  # run.progress_signal = "coverage"
            self.learning_progress.record_episode(row["episodes"], row.get("coverage"))
        return rows

    def _run_due_updates(self, new_steps: int) -> None:
        """Advance env steps by `new_steps`; run the updates due (`Pacing.due_updates`: one per `update_every` steps
        once warm); λ moves per step."""
        self.counters["env_steps"] += new_steps
        self.pacing.record_insert(new_steps)
        advanced = 0
        for _ in range(self.pacing.due_updates()):
            self.update()
            step = min(self.config.maddpg.update_every, new_steps - advanced)
            self.schedule.advance(step)  # Algorithm 1: λ += Δλ after the update of this env step
            advanced += step
        self.schedule.advance(new_steps - advanced)

    def update(self) -> dict[str, Any]:
        """One synchronous CMCL update (§3.8): the teacher and ICM steps due at their ratios per update
        (`teachers.steps_per_update`, `icm.steps_per_update`, by `cmcl.replay.pacing.Pacing`, as in the service),
        scoring, priorities at λ, MADDPG."""
        cfg, c, pacing = self.config, self.counters, self.pacing
        stats: dict[str, Any] = {}
        pacing.record_updates(1)  # this update: the teachers and the ICM owe their steps for it
        teacher_steps, icm_steps = pacing.due_teacher_steps(), pacing.due_icm_steps()
        pacing.record_teacher_steps(range(len(pacing.teachers)), teacher_steps)
        for _ in range(teacher_steps):
            teacher_loss = self._teacher_step()
            if teacher_loss is not None:
                stats["teacher_loss"] = teacher_loss
        icm = None
        pacing.record_icm_steps(icm_steps)
        for _ in range(icm_steps):
            icm = self._icm_step()
        if icm is not None:
            stats["icm_inverse_loss"] = float(np.mean(icm["inverse_loss"]))
            stats["icm_forward_loss"] = float(np.mean(icm["forward_loss"]))
        # A11 and §3.8's rescoring, amortised: new rows are scored before anything samples them
        slots = self.scoring.rescore_rows(self.replay, cfg.teachers.rescore_rows_per_update)
        for start in range(0, slots.size, RESCORE_CHUNK):
            self._score(buffer_steps.score_rows(self.replay, slots[start:start + RESCORE_CHUNK]))
        if self.prioritized:
            self.replay.recompute_priorities(self.schedule.lam)
        result = self._learner_step()
        stats["critic_loss"] = result["critic_loss"]
        self.learning_progress.record(c["episodes"], float(np.mean(result["critic_loss"])),
                                      agent_mean(result["critic_loss_normalised"]))
        stats["actor_loss"] = result["actor_loss"]
        stats.update({k: v for k, v in result.items() if k in ASSIGNMENT_STATS})  # maddpg.assignment_loss > 0 only
        c["updates"] += 1
        self.last_stats = stats
        return stats

    def _teacher_step(self) -> float | None:
        """One Adam step of every teacher on a batch from its own fold (eq. 9); None until every fold holds rows."""
        if self.teachers is None or (self.replay.storage.fold_counts() == 0).any():
            return None
        t = self.config.teachers
        draws = buffer_steps.teacher_fit_draws(t.fit_batch, self.layout.teacher_agents)
        slots = buffer_steps.fold_batch_slots(self.replay, range(t.num_folds), t.batch_size, self.rng["teacher"], draws)
        return network_steps.fit_teachers(self.teachers, buffer_steps.rows_at(self.replay, slots),
                                          self.layout.teacher_agents, self.maddpg)

    def _icm_step(self) -> dict[str, Any] | None:
        """One ICM step on S rows drawn uniformly from the buffer (§3.4); None without an ICM."""
        if self.icm is None:
            return None
        slots = buffer_steps.uniform_slots(self.replay, (1, self.config.icm.batch_size), self.rng["icm"])
        rows = buffer_steps.rows_at(self.replay, slots, ("obs", "act", "next_obs"))
        return network_steps.fit_icm(self.icm, rows, self.layout.icm_agents)

    def _score(self, work: Rows) -> None:
        """Score rows with every teacher (c, eqs. 10–11), the ICM (ρ, eq. 18) and, for ACL td_self, the online
        critics' |δ|; the scores go into the buffer's columns."""
        rows, slots, gens, layout = work.rows, work.slots, work.generations, self.layout
        stamp = self.counters["updates"]
        if self.teachers is not None:
            errors = network_steps.teacher_errors(self.teachers, rows, layout.teacher_agents, self.maddpg,
                                                  layout.teacher_error_squared)
            self.scoring.write_difficulty(self.replay, slots, gens, range(self.config.teachers.num_folds), errors,
                                          stamp)
        if self.icm is not None:
            rho = network_steps.curiosity_values(self.icm, rows, layout.icm_agents)
            self.scoring.write_curiosity(self.replay, slots, gens, rho, stamp)
        if self.scoring.online_td:
            self.scoring.write_online_td(self.replay, slots, gens, network_steps.online_td_abs(self.maddpg, rows),
                                         stamp)

    def _learner_step(self) -> dict[str, Any]:
        """Every agent draws its own minibatch, one batched MADDPG update, the per-row losses fed back to the
        samplers that ask for them."""
        cfg, layout = self.config, self.layout
        beta = beta_is(cfg, self.counters["env_steps"])
        betas = [beta if isw else 0.0 for isw in layout.importance_weights]
        batch = buffer_steps.sample_owner_batches(self.replay, 1, cfg.maddpg.batch_size, self.sampler_rngs, betas,
                                                  layout.candidates, layout.uniform_actor, layout.permuted_select)
        minibatch, slots, generations = network_steps.choose_minibatch(
            self.maddpg, batch, 0, any(layout.importance_weights), layout.select)
        if batch.select_u is not None:  # the picked rows' reward-bearing share, per agent (the sampling's effect)
            self.picked_rewarded += (minibatch["rew"][self.agents, :, self.agents] > 0).mean(1)
            self.picked_count += 1
        stats = network_steps.learner_update(self.maddpg, minibatch, self.icm, layout.icm_agents,
                                             cfg.icm.intrinsic_reward_coef)
        target = stats.get("target_td_abs")
        feedback = LearnerFeedback(slots[None], generations[None], np.asarray(stats["td_abs"])[None],
                                   target_td_abs=None if target is None else np.asarray(target)[None])
        buffer_steps.apply_learner_feedback(self.replay, layout, feedback)
        return stats

    # ------------------------------------------------------------------ metrics rows (cmcl/loop/metrics_rows.py)
    def progress_row(self, elapsed: float, rate: dict[str, float], segment: float | None = None) -> dict[str, Any]:
        """A 'progress' metrics row: counters, λ, losses, priority statistics and window means."""
        return progress_row(self, elapsed, rate, segment)

    def format_progress(self, row: dict[str, Any]) -> str:
        """One terminal line from a progress row."""
        return format_progress(self, row)

    # ------------------------------------------------------------------ checkpoints (cmcl/loop/checkpoint.py)
    def state_dict(self) -> dict[str, Any]:
        """Everything needed to continue the run except the replay contents (saved as a msgpack snapshot)."""
        return loop_state(self)

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore a `state_dict()`, world states included, so a resumed run continues exactly."""
        load_loop_state(self, state)

    def save_checkpoint(self) -> Path | None:
        """Write the replay snapshot, then the checkpoint (last: never one without its replay), into the run
        directory."""
        return save_loop_checkpoint(self)

    def restore(self, checkpoint: Path) -> None:
        """Load a checkpoint and its replay snapshot, each checked against its digest file before anything changes."""
        restore_loop(self, checkpoint)

    # ------------------------------------------------------------------ main loop
    def run(self, stop: Callable[[], bool] | None = None) -> dict[str, Any]:
        """Train until run.episodes episodes have finished, the coverage target `run.stop_coverage` is reached,
        learning stops progressing (`run.stop_progress`), the budget `run.max_seconds` is spent or `stop()` says so
        (polled after every batched env step: a graceful SIGINT / SIGTERM); checkpoints at the end in every case;
        returns the final progress row."""
        cfg, c = self.config, self.counters
        clock = RunClock(before_s=self.elapsed_s)  # goes on from the checkpoint; run.max_seconds is this command's
        last_t = time.perf_counter()
        last = {"env_steps": c["env_steps"], "updates": c["updates"]}
        next_log = (c["episodes"] // cfg.run.log_every + 1) * cfg.run.log_every
        ce = cfg.run.checkpoint_every
        next_ckpt = (c["episodes"] // ce + 1) * ce if ce else None
        row: dict[str, Any] = {}
        while c["episodes"] < cfg.run.episodes:
            for episode_row in self.env_step():
                episode_row["elapsed_s"] = clock.elapsed()
                if self.run_dir is not None:
                    self.run_dir.log(episode_row)
            self.stopped = stop is not None and stop()
            done = (c["episodes"] >= cfg.run.episodes or solved(self.window, cfg.run) or self.stopped
                    or self.learning_progress.plateaued
                    or (cfg.run.max_seconds > 0 and clock.segment() >= cfg.run.max_seconds))
            if c["episodes"] >= next_log or done:
                now = time.perf_counter()
                dt = max(now - last_t, 1e-9)
                rate = {"env_steps_per_s": (c["env_steps"] - last["env_steps"]) / dt,
                        "updates_per_s": (c["updates"] - last["updates"]) / dt}
                row = self.progress_row(clock.elapsed(now), rate, clock.segment(now))
                if self.run_dir is not None:
                    self.run_dir.log(row)
                if self.progress is not None:
                    self.progress(self.format_progress(row))
                last_t, last = now, {"env_steps": c["env_steps"], "updates": c["updates"]}
                next_log = (c["episodes"] // cfg.run.log_every + 1) * cfg.run.log_every
            now = time.perf_counter()
            self.elapsed_s, self.segment_s = clock.elapsed(now), clock.segment(now)
            if next_ckpt is not None and (c["episodes"] >= next_ckpt or done):
                self.save_checkpoint()
                next_ckpt = (c["episodes"] // ce + 1) * ce
            if done:
                break
        if ce == 0:
            self.save_checkpoint()
        return row

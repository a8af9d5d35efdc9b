"""The pacing of the updates, one object for both runners (ALGORITHM.md §3.8–3.9, DESIGN.md data flow step 7).

Three ratios, each held by a `cmcl.replay.ratelimit.RateLimiter`:

* learner updates per env step: Algorithm 1's `if |D| ≥ W and t mod update_every == 0` (§3.8) over B = env.num_envs
  worlds stepped in lock-step (the inline loop's batched env step, the rollout worker's too), the one warm-up rule of
  both runners: a batched step stores B transitions at once, then |D| is checked, so once the buffer holds
  W = max(1, maddpg.warmup) transitions an update is owed for every env step t (counted from 1) with
  t mod update_every == 0 from the first env step of the batched step that completed the warm-up, P + 1 with
  P = B · floor((W − 1) / B). As a limiter: ratio 1 / update_every, warm-up W, target counted from
  O = update_every · floor(P / update_every), so that floor((t − O) / update_every) counts those steps in (P, t];
* teacher fit steps per learner update: teachers.steps_per_update, one limiter per fold (its fit steps);
* ICM fit steps per learner update: icm.steps_per_update.

Teachers / the ICM have limiters only when some team uses them. The replay server (`services.roles.replay_server`) asks
`status` how much work each role may be given now, each ratio held within a slack (the calls' sizes plus
`service.slack_updates`), so that on the service the actors overlap instead of waiting for each other; in one
process (`--runner inline`) the same allowances are handed out one call after the other.

Built by `pacing_from_config`, the one place the config's ratios become limiters. Pure Python and numpy, no Ray.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from cmcl.replay.messages import PacingStatus
from cmcl.replay.ratelimit import RateLimiter, slack_for


class Pacing:
    """The learner's limiter (updates per env step), one per teacher fold and the ICM's (fit steps per update);
    teachers is [] and icm None when no team uses them. Build with `pacing_from_config`."""

    def __init__(self, learner: RateLimiter, teachers: list[RateLimiter], icm: RateLimiter | None):
        self.learner, self.teachers, self.icm = learner, teachers, icm

    @property
    def scorers(self) -> list[RateLimiter]:
        """The limiters of every teacher fold and of the ICM."""
        return [*self.teachers, *([self.icm] if self.icm is not None else [])]

    @property
    def warm(self) -> bool:
        """The buffer holds W = max(1, maddpg.warmup) transitions: learner, teacher and ICM work may start."""
        return self.learner.warmed_up

    # ------------------------------------------------------------------ what may be handed out (replay server)
    def status(self, fold_counts: np.ndarray) -> PacingStatus:
        """Work each role may be given now; fold_counts: int64[K] rows stored per fold."""
        own = self.learner.allowed_samples()  # 0 before the warm-up ends
        # the learner may not run ahead of the teachers / ICM by more than their slack
        allowed = min([own, *(lim.allowed_inserts() for lim in self.scorers)])
        held_by = "" if allowed > 0 else "warmup" if not self.warm else "env_steps" if own == 0 else "scores"
        return PacingStatus(allowed_updates=allowed, allowed_inserts=self.learner.allowed_inserts(),
                            update_deficit=self.learner.deficit if self.warm else 0.0,
                            scoring_deficit=self.scoring_deficit(fold_counts),
                            teacher_allowed=tuple(self.teacher_steps_allowed([f]) for f in range(len(self.teachers))),
                            icm_allowed=self.icm_steps_allowed(), updates_held_by=held_by)

    def teacher_steps_allowed(self, folds: Iterable[int]) -> int:
        """Fit steps the teachers of `folds` may be given now (each fold within its slack); 0 before warm-up."""
        if not self.warm or not self.teachers:
            return 0
        return min((self.teachers[f].allowed_samples() for f in folds), default=0)

    def icm_steps_allowed(self) -> int:
        """ICM fit steps that may be given now; 0 before warm-up or without an ICM."""
        return self.icm.allowed_samples() if self.warm and self.icm is not None else 0

    def scoring_deficit(self, fold_counts: np.ndarray) -> float:
        """Teacher / ICM steps still owed to the learner's updates (the largest over those that can get work).

        A teacher whose fold holds no row yet cannot be given work, so it does not count; nothing counts before
        the warm-up ends (no scoring work is handed out before then).
        """
        if not self.warm:
            return 0.0
        owed = [lim.deficit for f, lim in enumerate(self.teachers) if fold_counts[f] > 0]
        owed += [self.icm.deficit] if self.icm is not None else []
        return float(max(owed, default=0.0))

    # ------------------------------------------------------------------ what happened
    def record_insert(self, env_steps: int) -> None:
        """env_steps new transitions were stored (the learner may do more updates)."""
        self.learner.record_insert(env_steps)

    def record_updates(self, updates: int) -> None:
        """`updates` learner updates were run or handed out (the teachers and the ICM owe more fit steps)."""
        self.learner.record_sample(updates)
        for lim in self.scorers:
            lim.record_insert(updates)

    def record_teacher_steps(self, folds: Iterable[int], steps: int) -> None:
        """`steps` fit steps of the teachers of each fold in `folds` were run or handed out."""
        for f in folds:
            self.teachers[f].record_sample(steps)

    def record_icm_steps(self, steps: int) -> None:
        """`steps` ICM fit steps were run or handed out (without an ICM only 0 may be recorded)."""
        if self.icm is None and steps:
            raise ValueError(f"steps must be 0 without an ICM, got steps={steps!r}")
        if self.icm is not None:
            self.icm.record_sample(steps)

    # ------------------------------------------------------------------ state
    def state_dict(self) -> dict[str, Any]:
        """The limiters' states under the keys of the replay server's snapshot (also the inline checkpoint's)."""
        return {"learner_limit": self.learner.state_dict(),
                "teacher_limits": [lim.state_dict() for lim in self.teachers],
                "icm_limit": self.icm.state_dict() if self.icm is not None else {}}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore `state_dict()` output (ValueError naming the key and the setting that differs)."""
        learner = state["learner_limit"]
        teachers = state["teacher_limits"]
        if len(teachers) != len(self.teachers):
            raise ValueError(f"teacher_limits: the state has {len(teachers)} folds' limiters, this config "
                             f"{len(self.teachers)}")
        parts = [("learner_limit", self.learner, learner)]
        parts += [(f"teacher_limits[{f}]", self.teachers[f], saved) for f, saved in enumerate(teachers)]
        parts += [("icm_limit", self.icm, state["icm_limit"])] if self.icm is not None else []
        for key, lim, saved in parts:
            try:
                lim.load_state_dict(saved)
            except ValueError as err:
                raise ValueError(f"{key}: {err}") from None


def pacing_from_config(config: Any, asynchronous: bool = False) -> Pacing:
    """The pacing of a `cmcl.config.Config` (units in the module docstring).

    asynchronous=True, the replay server's: its slack fits a rollout chunk (env.num_envs × env.episode_length
    transitions) and a call's service.fit_steps_per_call fit steps, plus service.slack_updates learner updates of
    drift between the roles (the learner's slack is at least it, each scorer's grows by it). False: the tight form
    (chunks of one batched env step, one fit step, no extra slack), which the tests of the limiters' arithmetic read.
    """
    env, every = config.env, config.maddpg.update_every
    insert_chunk = env.num_envs * env.episode_length if asynchronous else env.num_envs
    fit_chunk = config.service.fit_steps_per_call if asynchronous else 1
    extra_slack = float(config.service.slack_updates) if asynchronous else 0.0
    ratio, warmup = 1.0 / every, max(1, config.maddpg.warmup)
    stored_before = env.num_envs * ((warmup - 1) // env.num_envs)  # P: env steps before the warming batched step
    start = every * (stored_before // every)
    learner = RateLimiter(ratio, warmup=warmup, start=start,
                          slack=max(slack_for(ratio, insert_chunk=insert_chunk), ratio * (warmup - start), extra_slack))
    teams = config.teams.values()
    teachers, icm = [], None
    if any(t.uses_teachers for t in teams):
        ratio = config.teachers.steps_per_update
        slack = slack_for(ratio, sample_chunk=fit_chunk) + extra_slack
        teachers = [RateLimiter(ratio, slack=slack) for _ in range(config.teachers.num_folds)]
    if config.trains_icm:
        ratio = config.icm.steps_per_update
        icm = RateLimiter(ratio, slack=slack_for(ratio, sample_chunk=fit_chunk) + extra_slack)
    return Pacing(learner, teachers, icm)

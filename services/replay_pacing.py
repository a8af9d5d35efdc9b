"""The replay server's rate limits: learner updates per inserted env step, teacher and ICM fit steps per update.

Where it sits: owned by `services.replay_server.ReplayServer`, which asks it how much work each role may be given
and tells it what was handed out. The ratios are the ones the inline loop keeps with `cmcl.replay.ratelimit.
steps_due` (`maddpg.update_every`, `teachers.steps_per_update`, `icm.steps_per_update`); here each holds within
a bounded slack (`service.slack_updates`) so that actors can run asynchronously. Numpy only.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cmcl.replay.ratelimit import limiters_from_config


class ReplayPacing:
    """One learner limiter (updates per env step), one per teacher fold and one for the ICM (fit steps per update),
    built once by `cmcl.replay.ratelimit.limiters_from_config` with the service's chunk sizes and slack."""

    def __init__(self, cfg: Any):
        limiters = limiters_from_config(cfg, insert_chunk=cfg.env.num_envs * cfg.env.episode_length,
                                        fit_chunk=cfg.service.fit_steps_per_call,
                                        extra_slack=cfg.service.slack_updates)
        self.learner, self.teachers, self.icm = limiters.learner, limiters.teachers, limiters.icm
        self.scorers = limiters.scorers

    def status(self, ready: bool, fold_counts: np.ndarray) -> dict[str, Any]:
        """Work each role may be given now; `ready`: the buffer holds its minimum size; fold_counts int64[K]."""
        allowed = self.learner.allowed_samples() if ready else 0
        for lim in self.scorers:  # the learner may not run ahead of the teachers / ICM by more than their slack
            allowed = min(allowed, lim.allowed_inserts())
        return {"allowed_updates": allowed, "allowed_inserts": self.learner.allowed_inserts(),
                "update_deficit": self.learner.deficit if self.learner.warmed_up else 0.0,
                "scoring_deficit": self.scoring_deficit(ready, fold_counts),
                "teacher_allowed": tuple(lim.allowed_samples() for lim in self.teachers),
                "icm_allowed": self.icm.allowed_samples() if self.icm is not None else 0}

    def scoring_deficit(self, ready: bool, fold_counts: np.ndarray) -> float:
        """Teacher / ICM steps still owed to the learner's updates (the largest over those that can get work).

        A teacher whose fold holds no row yet cannot be given work, so it does not count; nothing counts before
        the buffer reaches its minimum size (no scoring work is handed out before then).
        """
        if not ready:
            return 0.0
        owed = [lim.deficit for f, lim in enumerate(self.teachers) if fold_counts[f] > 0]
        owed += [self.icm.deficit] if self.icm is not None else []
        return float(max(owed, default=0.0))

    def record_insert(self, env_steps: int) -> None:
        """env_steps new transitions were stored (the learner may do more updates)."""
        self.learner.record_insert(env_steps)

    def record_updates(self, updates: int) -> None:
        """`updates` learner minibatches were handed out (the teachers and the ICM owe more fit steps)."""
        self.learner.record_sample(updates)
        for lim in self.scorers:
            lim.record_insert(updates)

    def state_dict(self) -> dict[str, Any]:
        return {"learner_limit": self.learner.state_dict(),
                "teacher_limits": [lim.state_dict() for lim in self.teachers],
                "icm_limit": self.icm.state_dict() if self.icm is not None else {}}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore `state_dict()` output (the keys of the replay server's snapshot)."""
        self.learner.load_state_dict(state["learner_limit"])
        for lim, saved in zip(self.teachers, state["teacher_limits"], strict=True):
            lim.load_state_dict(saved)
        if self.icm is not None:
            self.icm.load_state_dict(state["icm_limit"])

"""Teacher trainer: fits the fold-k critics of every teacher-using agent (for its folds k) and scores other folds.

Where it sits: replay -> teacher -> scores back to replay (ALGORITHM.md §3.2, distributed as in §3.9). Teacher k
never sees rows outside fold k when fitting; its errors count only for rows outside fold k. Regression targets come from
the learner's published target actor and target critic (never from a teacher). One fit batch per step is shared
by all of this fold's agents (the `idx[1, K, S]` form of cmcl.learners.teachers.make_fit_batch).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from cmcl.learners.nets import joint_input
from cmcl.learners.teachers import TeacherEnsemble
from cmcl.learners.weights import load_published
from cmcl.system import agent_layout, build_maddpg, make_batched_env
from services.common import actor_setup, load_state, new_incarnation, save_state


class TeacherWorker:
    """The teacher critics of the folds `folds` for every teacher-using agent, as one stacked ensemble.

    By default each actor hosts one fold (K actors); `service.teacher_actors` can stack several folds in one
    actor (member a·F + i is agent slot a, i-th hosted fold), which batches better on few cores.
    """

    def __init__(self, config: Any, folds: list[int], seed: int, checkpoint_path: str | None = None):
        self.config = cfg = actor_setup(config)
        self.folds, self.incarnation, self.checkpoint_path = [int(f) for f in folds], new_incarnation(), checkpoint_path
        self.name = "teacher-" + "-".join(map(str, self.folds))
        self.layout = agent_layout(cfg, make_batched_env(cfg, num_envs=1))
        in_dim = self.layout.num_agents * (self.layout.obs_dim + self.layout.act_dim)
        self.teachers = TeacherEnsemble(len(self.layout.teacher_agents), in_dim=in_dim, num_folds=len(self.folds),
                                        hidden=cfg.teachers.hidden, lr=cfg.teachers.lr, seed=seed)
        self.targets = build_maddpg(cfg, self.layout, seed)  # only its target nets are used
        self.version, self.steps, self.scores, self.loss = -1, 0, 0, None
        state = load_state(checkpoint_path)
        self.resumed = state is not None
        if state is not None:
            self.teachers.load_state_dict(state["teachers"])
            self.steps, self.scores = int(state["steps"]), int(state["scores"])

    def _targets(self, rows: dict[str, np.ndarray]) -> torch.Tensor:
        """y [A_t, M] from the learner's target nets on joint rows (rew [M, N], next_obs [M, N, od])."""
        y = self.targets.td_targets(rows["rew"], rows["next_obs"], rows.get("done"), agents=self.layout.teacher_agents)
        return torch.as_tensor(y)

    def step(self, work: dict[str, Any] | None, published: dict[str, Any] | None
             ) -> tuple[dict[str, Any] | None, dict[str, Any]]:
        """Fit on work["fit"] ([steps, F, S, ...]: rows of each hosted fold), then score work["score"] rows.

        Returns (scores {folds, slots, generations, errors float32[M, A_t, F], updates, loss}, metrics report).
        """
        if work is None or published is None:
            return None, self.report()
        if published["version"] != self.version:
            load_published(self.targets, published["weights"], parts=("target_actor", "target_critic"))
            self.version = int(published["version"])
        fit, a_t = work["fit"], len(self.layout.teacher_agents)
        steps, f, s = fit["obs"].shape[:3]
        flat = {k: fit[k].reshape(steps * f * s, *fit[k].shape[3:]) for k in ("obs", "act", "rew", "next_obs",
                                                                                 "done")}
        # the targets of every fit step at once: they come from fixed (published) target nets
        x_all = joint_input(torch.as_tensor(flat["obs"]), torch.as_tensor(flat["act"])).reshape(steps, f, s, -1)
        y_all = self._targets(flat).reshape(a_t, steps, f, s)  # [A_t, steps, F, S]
        for i in range(steps):  # member (a, i) sees only the batch of its own fold
            loss = self.teachers.fit_step(x_all[i].expand(a_t, -1, -1, -1), y_all[:, i])
            self.loss = float(loss.mean())
        self.steps += steps
        score = work["score"]
        x = joint_input(torch.as_tensor(score["obs"]), torch.as_tensor(score["act"]))
        squared = self.config.teachers.difficulty_error == "squared"
        errors = self.teachers.errors(x, self._targets(score), squared=squared).transpose(1, 0, 2).copy()  # [M, A_t, F]
        self.scores += int(errors.shape[0])
        return {"folds": self.folds, "slots": score["slots"], "generations": score["generations"], "errors": errors,
                "updates": work["updates"], "loss": self.loss if self.loss is not None else 0.0}, self.report()

    def report(self) -> dict[str, Any]:
        """Metrics report of this teacher (its weight version; steps / scores are reported by the replay)."""
        return {"source": self.name, "role": "teacher", "incarnation": self.incarnation,
                "resumed": self.resumed, "weight_version": max(self.version, 0)}

    def save(self) -> str | None:
        """Write this teacher's checkpoint atomically."""
        return save_state(self.checkpoint_path, {"teachers": self.teachers.state_dict(), "steps": self.steps,
                                                 "scores": self.scores})

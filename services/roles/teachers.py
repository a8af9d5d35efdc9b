"""Teacher actor: fits the fold-k critics of every teacher-using agent (for its folds k) and scores other folds.

Where it sits: replay -> teachers -> scores back to replay (ALGORITHM.md §3.2, distributed as in §3.9), one of the
scorers: a `ScoreWork` in, `Scores` out. The shell around `cmcl.learners.network_steps.fit_teachers` /
`teacher_errors`.
Teacher k never sees rows outside fold k when fitting; its errors count only for rows outside fold k (the replay
server's `DifficultyTable`). Regression targets come from the learner's published target actor and target critic (never
from a teacher). One fit batch per step is shared by all of this fold's agents (`teachers.fit_batch="shared"`), or
one per agent ("per_agent"), as the replay server draws them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cmcl.learners import network_steps
from cmcl.learners.weights import load_published
from cmcl.replay.messages import DIFFICULTY, Scorer, Scores, ScoreWork
from cmcl.scorers.teachers import TeacherEnsemble
from cmcl.system import build_maddpg, build_teachers, layout_of
from services.observability.report_schema import Report
from services.runtime.common import actor_setup, load_state, new_incarnation, save_state


class TeacherWorker:
    """The teacher critics of the folds `folds` for every teacher-using agent, as one stacked ensemble.

    By default each actor hosts one fold (K actors); `service.teacher_actors` can stack several folds in one
    actor (member a·F + i is agent slot a, i-th hosted fold), which batches better on few cores.
    """

    def __init__(self, config: Any, folds: list[int], seed: int, checkpoint_path: str | None = None):
        self.config = cfg = actor_setup(config)
        self.folds, self.incarnation, self.checkpoint_path = [int(f) for f in folds], new_incarnation(), checkpoint_path
        self.name = "teacher-" + "-".join(map(str, self.folds))
        self.layout = layout_of(cfg)
        teachers = build_teachers(cfg, self.layout, seed, num_folds=len(self.folds))
        if teachers is None:
            raise ValueError("no team of this config uses teachers (algorithm acl or cmcl): no teacher actor to run")
        self.teachers: TeacherEnsemble = teachers
        self.targets = build_maddpg(cfg, self.layout, seed)  # only its target nets are used
        self.version, self.steps, self.scores, self.loss = -1, 0, 0, 0.0
        state, refused = load_state(checkpoint_path)
        self.checkpoints_refused = len(refused)  # files refused at this start (manifest checks)
        self.resumed = state is not None
        if state is not None:
            self.teachers.load_state_dict(state["teachers"])
            self.steps, self.scores = int(state["steps"]), int(state["scores"])

    @property
    def scorer(self) -> Scorer:
        """This scorer: the teachers of its folds, writing the difficulty column."""
        return Scorer(DIFFICULTY, tuple(self.folds))

    def score(self, work: ScoreWork | None, published: dict[str, Any] | None) -> tuple[Scores | None, Report]:
        """Fit on work.fit ([steps, B, F, S, ...]: rows of each hosted fold), then score the work.score rows.

        Returns (Scores with values = errors float32[M, A_t, F] (eq. 10), metrics report).
        """
        if work is None or published is None:
            return None, self.report()
        if published["version"] != self.version:
            load_published(self.targets, published["weights"], parts=("target_actor", "target_critic"))
            self.version = int(published["version"])
        agents = self.layout.teacher_agents
        loss = network_steps.fit_teachers(self.teachers, work.fit, agents, self.targets)
        self.loss = self.loss if np.isnan(loss) else loss
        self.steps += int(work.fit["obs"].shape[0])
        # [M, A_t, F]
        errors = network_steps.teacher_errors(self.teachers, work.score.rows, agents, self.targets,
                                              self.layout.teacher_error_squared)
        self.scores += int(errors.shape[0])
        return Scores(self.scorer, work.score.slots, work.score.generations, errors, work.updates, self.loss,
                      self.incarnation), self.report()

    def report(self) -> Report:
        """Metrics report of this teacher (its weight version; steps / scores are reported by the replay)."""
        return Report(source=self.name, role="teacher", incarnation=self.incarnation, resumed=self.resumed,
                      checkpoints_refused=self.checkpoints_refused,
                      weight_version=max(self.version, 0))

    def save(self) -> str | None:
        """Write this teacher's checkpoint atomically."""
        return save_state(self.checkpoint_path, {"teachers": self.teachers.state_dict(), "steps": self.steps,
                                                 "scores": self.scores})

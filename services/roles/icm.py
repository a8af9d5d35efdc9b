"""ICM actor: trains every curiosity-using agent's ICM on uniform replay batches and scores buffer rows with ρ.

Where it sits: replay -> ICM -> curiosity scores back to replay (ALGORITHM.md §3.4, distributed as in §3.9), one of
the scorers: a `ScoreWork` in, `Scores` out. The shell around `cmcl.learners.network_steps.fit_icm` /
`curiosity_values`. It needs no policy weights: the ICM models (o, a, o') only.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cmcl.learners import network_steps
from cmcl.replay.messages import CURIOSITY, Scorer, Scores, ScoreWork
from cmcl.system import build_icm, layout_of
from services.observability.report_schema import Report
from services.runtime.common import actor_setup, load_state, new_incarnation, save_state


class ICMWorker:
    """Per-agent ICMs of the curiosity agents, as one stacked module."""

    def __init__(self, config: Any, seed: int, checkpoint_path: str | None = None):
        self.config = cfg = actor_setup(config)
        self.incarnation, self.checkpoint_path = new_incarnation(), checkpoint_path
        self.layout = layout_of(cfg)
        self.icm = build_icm(cfg, self.layout, seed)
        if self.icm is None:
            raise ValueError("no team uses curiosity: the ICM actor is not needed for this config")
        self.loss = 0.0
        state, refused = load_state(checkpoint_path)
        self.checkpoints_refused = len(refused)  # files refused at this start (manifest checks)
        self.resumed = state is not None
        if state is not None:
            self.icm.load_state_dict(state["icm"])

    scorer = Scorer(CURIOSITY)  # this scorer: the ICM, writing the curiosity column

    def score(self, work: ScoreWork | None, published: dict[str, Any] | None = None
              ) -> tuple[Scores | None, Report]:
        """Fit on work.fit ([steps, S, N, ·] rows), then return Scores with ρ float32[M, A_c] (eq. 18) of the
        work.score rows. `published` (the learner's weights) is not needed: the ICM models (o, a, o') only."""
        if work is None:
            return None, self.report()
        agents = self.layout.icm_agents
        out = {} if self.config.icm.frozen else network_steps.fit_icm(self.icm, work.fit, agents)
        if out:
            self.loss = float(np.mean(out["inverse_loss"]) + np.mean(out["forward_loss"]))
        rho = network_steps.curiosity_values(self.icm, work.score.rows, agents)
        return Scores(self.scorer, work.score.slots, work.score.generations, rho, work.updates, self.loss,
                      self.incarnation), self.report()

    def report(self) -> Report:
        """Metrics report (steps / scores are counted by the replay server)."""
        return Report(source="icm", role="icm", incarnation=self.incarnation, resumed=self.resumed,
                      checkpoints_refused=self.checkpoints_refused)

    def save(self) -> str | None:
        """Write the ICM checkpoint atomically."""
        return save_state(self.checkpoint_path, {"icm": self.icm.state_dict()})

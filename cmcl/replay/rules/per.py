"""per: PER-MADDPG (Schaul et al.; the paper's baseline, ALGORITHM.md §5): p = |δ| + ε_p from the learner's TD errors.

New slots enter at the running maximum priority (starting at 1.0), which each feedback raises; sampled with Schaul's
α_s = 0.6 and IS weights on the critic by default (A8, A9). |δ| is computed by the critic with the mask of absent
agents, so rows carried from fewer agents (run.carry_replay) may be drawn.
"""

from __future__ import annotations

import numpy as np

from cmcl.replay.rules.contract import Needs, Rule
from cmcl.replay.sampling import SamplerArgs, _ProportionalSampling
from cmcl.replay.storage import TransitionStorage


class PrioritizedSampling(_ProportionalSampling):
    """PER (Schaul et al.): p = |δ| + ε_p from the learner's TD errors; new slots at the running maximum."""

    name = "per"

    def __init__(self, args: SamplerArgs):
        super().__init__(args)
        self.max_priority = 1.0  # the PER rule: starts at 1.0, raised by every update

    def initial_priority(self, slots: np.ndarray) -> float:
        return self.max_priority

    def priority_of(self, scores: dict[str, np.ndarray]) -> np.ndarray:
        """The raw priority of rows from their learner scores (float[k] each): |δ| + ε_p."""
        return scores["td_abs"] + self.eps

    def feedback(self, storage: TransitionStorage, agent: int, slots: np.ndarray, generations: np.ndarray,
                 scores: dict[str, np.ndarray]) -> tuple[int, bool]:
        """|δ| into the agent's "td_abs" score column, and p = `priority_of` for the fresh slots (stale ones are
        dropped), raising the running maximum. Returns (accepted, False: no curriculum column changed)."""
        td = scores["td_abs"]
        accepted = storage.update_scores("td_abs", slots, generations, td.astype(np.float32), agents=[agent])
        ok = storage.fresh_mask(slots, generations)
        self.update_priorities(slots[ok], {k: v[ok] for k, v in scores.items()})
        return accepted, False

    def update_priorities(self, slots: np.ndarray, scores: dict[str, np.ndarray]) -> None:
        """p = `priority_of(scores)` for fresh slots int64[k], and raise the running maximum."""
        if slots.size:
            p = self.priority_of(scores)
            self.sampler.update(slots, p)
            self.max_priority = max(self.max_priority, float(p.max()))

    def diagnostics(self) -> dict:
        return {**super().diagnostics(), "max_priority": self.max_priority}

    def state_dict(self) -> dict:
        return {**super().state_dict(), "max_priority": self.max_priority}

    def load_state_dict(self, state: dict, size: int) -> None:
        maxp = float(state["max_priority"])
        if not (np.isfinite(maxp) and maxp > 0):
            raise ValueError(f"max_priority must be finite and > 0, got {maxp!r}")
        super().load_state_dict(state, size)
        self.max_priority = maxp


RULE = Rule("per", "PER-MADDPG: p = |δ| + ε (Schaul et al.)", lambda args, options: PrioritizedSampling(args), "per",
            0.6, True, lambda team: Needs(learner_scores=("td_abs",)), paper=True, masks_absent_agents=True)

"""relo: ReLo (Sujit et al., NeurIPS 2023), PER with the reducible loss as the priority.

p_j = max(0, L_online(j) − L_target(j)) + ε_p with L = δ² the squared TD error of the row under the online critic and
under the target critic, against the same target y (reducible-loss repository: `priority = online_loss −
target_loss`, clipped at 0). A row the online critic fits worse than its slow-moving target has something left to
learn; a row that is noisy (high loss under both) does not. New rows enter at the running maximum, as in PER; the
learner returns both per-row errors for the rows it sampled: |δ| (LearnerFeedback.td_abs) and this rule's own
learner score, "target_td_abs" = |y − Q_target| (`TARGET_TD`, in LearnerFeedback.rule_scores).
"""

from __future__ import annotations

import numpy as np

from cmcl.replay.rules.contract import LearnerScore, Needs, Rule
from cmcl.replay.rules.per import PrioritizedSampling


class ReducibleLossSampling(PrioritizedSampling):
    """PER's sampler with p = max(0, δ_online² − δ_target²) + ε_p (float[k] scores "td_abs", "target_td_abs")."""

    name = "relo"

    def priority_of(self, scores: dict[str, np.ndarray]) -> np.ndarray:
        online, target = scores["td_abs"].astype(np.float64), scores["target_td_abs"].astype(np.float64)
        return np.maximum(online * online - target * target, 0.0) + self.eps


# |y − Q_target| [N, S] of the update's rows under the pre-step target critic (MADDPG.update's "target_td_abs")
TARGET_TD = LearnerScore("target_td_abs", lambda stats, minibatch: stats["target_td_abs"], target_critic=True)
RULE = Rule("relo", "ReLo: p = max(0, δ² − δ_target²) + ε (Sujit et al.)",
            lambda args, options: ReducibleLossSampling(args), "relo", 0.6, True,
            lambda team: Needs(learner_scores=("td_abs", TARGET_TD.name)), learner_scores=(TARGET_TD,))

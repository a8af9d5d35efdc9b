"""acl: the K-fold priority KP(ĉ, λ) alone (the paper's ablation, ALGORITHM.md §5), and the curriculum sampler that
acl and cmcl (cmcl.replay.rules.cmcl) share: p = KP(ĉ, λ) [+ η·CP(ρ̂)] + ε_p recomputed from the score columns at
each λ (eqs. 8, 12, 19); a row not yet scored gets the scored rows' mean sampling weight (`provisional_priority`,
A11). An acl team's difficulty comes from the K-fold teachers (`acl_variant = "teachers"`) or from the learner's own
|δ| on the row (`"td_self"`).
"""

from __future__ import annotations

import numpy as np

from cmcl.replay.priority import curriculum_priority
from cmcl.replay.rules.contract import Needs, Rule
from cmcl.replay.sampling import SamplerArgs, _ProportionalSampling
from cmcl.replay.storage import TransitionStorage

COVERAGE_WAITS = ", cov may wait"  # the part of KP_EXCLUDES a run without a coverage metric is not shown
KP_EXCLUDES = "normal while λ < 0.5: KP excludes the hardest rows" + COVERAGE_WAITS


class CurriculumSampling(_ProportionalSampling):
    """ACL / CMCL: the curriculum index of eq. 8 over agent `agent`'s score columns, recomputed at each λ.

    From SamplerArgs: eta (CMCL's η; ACL has η = 0), difficulty_source ("difficulty": teachers, "td_abs": ACL
    td_self, whose |δ| arrives as feedback), difficulty_norm, cp_input, lam_max, reversed_difficulty.
    """

    has_terms = True

    def __init__(self, args: SamplerArgs):
        super().__init__(args)
        self.name = args.algorithm
        self.eta = float(args.eta)  # 0 for every rule without η (the registry's build_sampler sees to it)
        self.difficulty_source, self.difficulty_norm = args.difficulty_source, args.difficulty_norm
        self.cp_input = args.cp_input
        self.lam_max, self.reversed_difficulty = float(args.lam_max), bool(args.reversed_difficulty)
        self.recomputes = True

    def initial_priority(self, slots: np.ndarray) -> float:
        return self.held_mean_priority(slots)

    def feedback(self, storage: TransitionStorage, agent: int, slots: np.ndarray, generations: np.ndarray,
                 scores: dict[str, np.ndarray]) -> tuple[int, bool]:
        """ACL td_self: the learner's |δ| into the "td_abs" column its difficulty comes from (a column changed);
        the teachers' variants take no feedback."""
        if self.difficulty_source != "td_abs":
            return int(np.size(slots)), False
        return storage.update_scores("td_abs", slots, generations, scores["td_abs"][:, None], agents=[agent]), True

    def terms(self, storage: TransitionStorage, lam: float) -> tuple[np.ndarray, ...]:
        """(c_hat, kp, cp, p, has_difficulty) float64[size] (bool for the last) of this agent over the valid rows
        at λ, from its score columns (`cmcl.replay.priority.curriculum_priority`); read-only."""
        size, a, col = storage.size, self.agent, self.difficulty_source
        return curriculum_priority(storage.scores[col][:size, a], storage.scored[col][:size, a],
                                   storage.scores["curiosity"][:size, a], storage.scored["curiosity"][:size, a],
                                   lam, self.eta, eps=self.eps, difficulty_norm=self.difficulty_norm,
                                   cp_input=self.cp_input, lam_max=self.lam_max,
                                   reversed_difficulty=self.reversed_difficulty, alpha=self.sampler.alpha)

    def recompute(self, storage: TransitionStorage, lam: float) -> np.ndarray:
        """p = CI + ε_p of eq. 8 over the valid rows at λ (`terms`)."""
        return self.terms(storage, lam)[3]


def _acl_needs(team) -> Needs:
    """td_self: the learner's |δ| is the difficulty; else the teachers'."""
    if team.acl_variant == "td_self":
        return Needs(learner_scores=("td_abs",), difficulty_source="td_abs")
    return Needs(teachers=True)


RULE = Rule("acl", "the K-fold priority KP(ĉ, λ) alone", lambda args, options: CurriculumSampling(args), "acl",
            needs=_acl_needs, paper=True, early_note=KP_EXCLUDES, uses_lambda=True)

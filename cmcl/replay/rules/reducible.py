"""rho: the reducible held-out loss, RHO-LOSS (Mindermann et al., ICML 2022) with the K-fold teachers as
the holdout model.

RHO-LOSS trains on the points whose training loss most exceeds the loss of a model that never saw them
(OATML/RHO-Loss, `selection_methods.py`: reducible loss = loss − irreducible loss). Here every row already has such a
model: the teachers not fitted on its fold (ALGORITHM.md §3.2), whose error ē_j is the row's difficulty column. So

    r_j = ℓ_j − ē_j,  ℓ_j = the learner's δ_j² (or |δ_j| when the teachers' error is |δ|, same units as ē_j),
    p_j = rank(r_j)/(M' − 1) + ε_p over the M' rows with both scores,

rank-normalised (as A1's difficulty) so the priority is invariant to the loss's scale. δ_j comes back as feedback on
the rows the learner sampled (the "td_abs" column); a row without both scores gets the scored rows' mean sampling
weight (`provisional_priority`, as CMCL's unscored rows).
"""

from __future__ import annotations

import numpy as np

from cmcl.replay.priority import provisional_priority
from cmcl.replay.rules.contract import Needs, Rule
from cmcl.replay.sampling import SamplerArgs, _ProportionalSampling
from cmcl.replay.storage import TransitionStorage


def rank01(x: np.ndarray) -> np.ndarray:
    """Ranks of float[M] scaled to [0, 1] (ties share their lowest rank; M ≤ 1 gives zeros) -> float64[M]."""
    m = x.size
    if m <= 1:
        return np.zeros(m)
    return np.searchsorted(np.sort(x), x, side="left") / (m - 1)


class HeldOutReducibleSampling(_ProportionalSampling):
    """p = rank(ℓ − ē) + ε_p over the rows holding the learner's loss and the teachers' held-out error."""

    name = "rho"

    def __init__(self, args: SamplerArgs):
        super().__init__(args)
        self.squared = bool(args.difficulty_squared)
        self.recomputes = True

    def initial_priority(self, slots: np.ndarray) -> float:
        """The held rows' mean sampling weight (ε_p in an empty buffer) until the next recompute."""
        return self.held_mean_priority(slots)

    def feedback(self, storage: TransitionStorage, agent: int, slots: np.ndarray, generations: np.ndarray,
                 scores: dict[str, np.ndarray]) -> tuple[int, bool]:
        """The learner's |δ| into the agent's "td_abs" column (a column changed: recompute)."""
        return storage.update_scores("td_abs", slots, generations, scores["td_abs"][:, None], agents=[agent]), True

    def recompute(self, storage: TransitionStorage, lam: float) -> np.ndarray:
        """p float64[size] over the valid rows (module docstring); λ is not used."""
        size, a = storage.size, self.agent
        td = storage.scores["td_abs"][:size, a].astype(np.float64)
        loss = td * td if self.squared else td
        held_out = storage.scores["difficulty"][:size, a].astype(np.float64)
        both = storage.scored["td_abs"][:size, a] & storage.scored["difficulty"][:size, a]
        p = np.full(size, self.eps)
        if both.any():
            p[both] = rank01(loss[both] - held_out[both]) + self.eps
            if not both.all():
                p[~both] = provisional_priority(p[both], self.sampler.alpha)
        return p


RULE = Rule("rho", "reducible held-out loss: rank(δ² − ē), ē the teachers' held-out error (RHO-LOSS)",
            lambda args, options: HeldOutReducibleSampling(args), "rho",
            needs=lambda team: Needs(teachers=True, learner_scores=("td_abs",)))

"""lp: held-out learning progress with staleness, where the teachers' error on a row is changing.

Learning-progress curricula (ALP-GMM, Portelas et al. 2019; SPMARL, ICML 2025) sample where a competence measure
moves. Here the measure is a row's held-out error ē_j (the teachers not fitted on its fold, its difficulty column),
which the rescoring rule refreshes as the teachers learn. At each recompute, for every row rescored since the last
one, progress_j = |ē_j(t) − ē_j(t−1)|. As in Prioritized Level Replay (Jiang et al., ICML 2021,
facebookresearch/level-replay `level_sampler.py`), the score distribution is rank-based and mixed with a staleness
distribution so that rows whose score is old get revisited:

    P_score(j) ∝ rank(progress_j)/(M' − 1) + ε_p     (rows without a progress value yet: the mean of the others)
    P_stale(j) ∝ draws − last_drawn_j                (draws since the row was last sampled, or since it was written)
    P(j) = (1 − ρ)·P_score(j) + ρ·P_stale(j),  ρ = teams.<team>.staleness (PLR's default 0.1)

The sampler holds P as its raw priorities (sampled with α = 1: the registry's default for this rule).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cmcl.field_docs import documented
from cmcl.replay.rules.contract import Needs, Range, Rule
from cmcl.replay.rules.reducible import rank01
from cmcl.replay.sampling import SamplerArgs, _ProportionalSampling
from cmcl.replay.storage import TransitionStorage

STALENESS = 0.1  # ρ's default (PLR's default staleness_coef)


@dataclass(frozen=True)
class ProgressOptions:
    """lp's own keys in its team's table (teams.<team>.staleness)."""

    staleness: float = documented(STALENESS, "ρ, the staleness mix of lp: P = (1 − ρ)·P_score + ρ·P_stale "
                                  "(PLR's staleness_coef)", rule=Range("must lie in [0, 1]", lambda v: 0 <= v <= 1))


class HeldOutProgressSampling(_ProportionalSampling):
    """P = (1 − ρ)·P_score(|Δē|) + ρ·P_stale (module docstring). State: the last held-out error seen per slot, the
    last progress, and the draw counter at each slot's last draw."""

    name = "lp"

    def __init__(self, args: SamplerArgs, staleness: float = STALENESS):
        super().__init__(args)
        self.staleness = float(staleness)  # ρ
        cap = args.capacity
        self.last_error = np.zeros(cap)  # ē_j at the previous recompute
        self.seen = np.zeros(cap, bool)  # ē_j has been seen once
        self.progress = np.zeros(cap)  # |ē_j(t) − ē_j(t−1)| at its last change
        self.has_progress = np.zeros(cap, bool)
        self.last_drawn = np.zeros(cap, np.int64)  # `draws` when the slot was last sampled (or written)
        self.draws = 0  # sample() calls so far
        self.recomputes = True

    def initial_priority(self, slots: np.ndarray) -> float:
        """A new row forgets the old row's history; it starts at ε_p until the next recompute."""
        self.seen[slots] = self.has_progress[slots] = False
        self.progress[slots] = self.last_error[slots] = 0.0
        self.last_drawn[slots] = self.draws
        return self.eps

    def recompute(self, storage: TransitionStorage, lam: float) -> np.ndarray:
        """P float64[size] over the valid rows (module docstring); λ is not used."""
        size, a = storage.size, self.agent
        error = storage.scores["difficulty"][:size, a].astype(np.float64)
        scored = storage.scored["difficulty"][:size, a]
        changed = scored & self.seen[:size] & (error != self.last_error[:size])
        self.progress[:size][changed] = np.abs(error[changed] - self.last_error[:size][changed])
        self.has_progress[:size] |= changed
        self.last_error[:size][scored] = error[scored]
        self.seen[:size] |= scored
        has = self.has_progress[:size]
        score = np.full(size, 1.0)
        if has.any():
            score[has] = rank01(self.progress[:size][has]) + self.eps
            score[~has] = score[has].mean()
        age = (self.draws - self.last_drawn[:size]).astype(np.float64)
        stale = age / age.sum() if age.sum() > 0 else np.full(size, 1.0 / max(size, 1))
        return (1.0 - self.staleness) * score / score.sum() + self.staleness * stale + self.eps

    def sample(self, n: int, size: int, rng: np.random.Generator, beta: float) -> tuple[np.ndarray, np.ndarray]:
        slots, weights = super().sample(n, size, rng, beta)
        self.draws += 1
        self.last_drawn[slots] = self.draws
        return slots, weights

    def state_dict(self) -> dict:
        return {**super().state_dict(), "last_error": self.last_error, "seen": self.seen, "progress": self.progress,
                "has_progress": self.has_progress, "last_drawn": self.last_drawn, "draws": self.draws}

    def load_state_dict(self, state: dict, size: int) -> None:
        cap = self.sampler.capacity
        arrays = {k: np.asarray(state[k]) for k in ("last_error", "seen", "progress", "has_progress", "last_drawn")}
        for k, v in arrays.items():
            if v.shape != (cap,):
                raise ValueError(f"{k} must have shape ({cap},), got {v.shape}")
        if not (np.all(np.isfinite(arrays["last_error"])) and np.all(np.isfinite(arrays["progress"]))):
            raise ValueError("last_error and progress must be finite")
        draws = int(state["draws"])
        if draws < 0 or arrays["last_drawn"].min(initial=0) < 0 or arrays["last_drawn"].max(initial=0) > draws:
            raise ValueError(f"last_drawn must lie in [0, draws={draws}]")
        super().load_state_dict(state, size)
        self.last_error, self.progress = arrays["last_error"].astype(np.float64), arrays["progress"].astype(np.float64)
        self.seen, self.has_progress = arrays["seen"].astype(bool), arrays["has_progress"].astype(bool)
        self.last_drawn, self.draws = arrays["last_drawn"].astype(np.int64), draws


RULE = Rule("lp", "held-out learning progress: rank |Δē| mixed with staleness (PLR)",
            lambda args, options: HeldOutProgressSampling(args, options.staleness), "lp", options=ProgressOptions,
            needs=lambda team: Needs(teachers=True))

"""The sampling distributions of replay, behind one closed protocol (ALGORITHM.md §3.6, §5, A8, A9, A11).

Where it sits: `cmcl.replay.buffer.ReplayBuffer` holds one sampler per agent, built from the agent's algorithm by the
registry (`cmcl.replay.registry`: one spec per algorithm names its sampler class; as Dopamine has one replay class per
sampling distribution). The buffer never asks what kind a sampler is; it calls the protocol on every one of them:

  added(slots)                        new slots int64[k] were written (their initial priority)
  feedback(storage, agent, slots, generations, scores) -> (accepted, scores_changed)
                                      the learner's per-row losses of the agent's sampled rows (LearnerScores
                                      columns: "td_abs" |y − Q|, "target_td_abs" |y − Q_target|, float[k])
  recompute(storage, lam) -> p | None the raw priority column float64[size] rebuilt from the score columns at λ
                                      (None: nothing to rebuild; `recomputes` says which samplers rebuild); the
                                      buffer applies the permuted control across all returned columns and hands
                                      each back through `set_priorities`
  sample(n, size, rng, beta) -> (slots int64[n], IS weights float32[n])
  probabilities(slots, size) -> float64[k]
  diagnostics() -> dict               scalars for metrics (e.g. PER's running maximum)
  state_dict() / load_state_dict(state, size)

  uniform ........ UniformSampling:     P(j) = 1/|D|; IS weights 1.
  per ............ PrioritizedSampling: p = |δ| + ε_p from feedback; new slots at the running maximum priority
                                        (starts at 1.0), which each feedback raises.
  acl, cmcl ...... CurriculumSampling:  p = KP(ĉ, λ) [+ η·CP(ρ̂)] + ε_p recomputed from the score columns
                                        (`terms`, eqs. 8, 12, 19); a row not yet scored gets the
                                        mean sampling weight of the scored rows (`provisional_priority`, A11).
  other rules .... cmcl/replay/rules/, one file each (cmcl.replay.registry registers them).
Prioritized draws use P(j) = p_j^α / Σ_k p_k^α (eq. 20) from a `cmcl.replay.sampler.PrioritySampler` (cdf or sum
tree backend, vectorised), mixed with a uniform floor u when one is set: P_u(j) = (1 − u)·P(j) + u/|D|.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cmcl.replay.priority import curriculum_priority, provisional_priority
from cmcl.replay.sampler import PrioritySampler, importance_weights
from cmcl.replay.storage import TransitionStorage

DIFFICULTY_SOURCES = ("difficulty", "td_abs")  # "td_abs" = ACL's td_self variant (§5)
LEARNER_SCORES = ("td_abs", "target_td_abs")  # per-row learner losses a sampler can ask for (cmcl.replay.registry)


@dataclass(frozen=True)
class SamplerArgs:
    """What a sampler is built from (cmcl.replay.registry builds one per agent from the config).

    capacity: buffer slots. alpha: α_s of eq. 20. backend: "cdf" | "sumtree". eps: ε_p. agent: the agent index.
    algorithm: its registry name. eta: η (CMCL). difficulty_source: "difficulty" | "td_abs". difficulty_norm:
    "rank" | "max" (A1). difficulty_squared: the teachers' held-out error is a squared TD error (else |δ|).
    cp_input: "std" | "raw" (A7). lam_max: cap on λ. reversed_difficulty: the anti-curriculum control.
    permuted: the permuted control is on (rules whose priorities come from feedback then return them from
    `recompute`, so that the buffer shuffles them). floor: uniform floor u in [0, 1)."""

    capacity: int
    alpha: float
    backend: str
    eps: float
    agent: int = 0
    algorithm: str = ""
    eta: float = 0.0
    difficulty_source: str = "difficulty"
    difficulty_norm: str = "rank"
    difficulty_squared: bool = True
    cp_input: str = "std"
    lam_max: float = 1.0
    reversed_difficulty: bool = False
    permuted: bool = False
    floor: float = 0.0


class UniformSampling:
    """MADDPG's sampling: every valid slot equally likely, IS weights of 1 (no state)."""

    name = "uniform"  # the sampling distribution's name in the metrics ("sampling.modes")
    recomputes = False  # `recompute` never returns priorities

    def __init__(self, args: SamplerArgs | None = None):
        """Nothing to hold; `args` is accepted so that every sampler is built alike."""

    def added(self, slots: np.ndarray) -> None:
        """New slots int64[k] were written: nothing to do."""

    def feedback(self, storage: TransitionStorage, agent: int, slots: np.ndarray, generations: np.ndarray,
                 scores: dict[str, np.ndarray]) -> tuple[int, bool]:
        """Uniform sampling asks for no feedback: (k accepted, no score column changed)."""
        return int(np.size(slots)), False

    def recompute(self, storage: TransitionStorage, lam: float) -> np.ndarray | None:
        """Nothing to rebuild."""
        return None

    def diagnostics(self) -> dict:
        return {}

    def probabilities(self, slots: np.ndarray, size: int) -> np.ndarray:
        """P(j) = 1/|D| for valid slots int64[k] -> float64[k]."""
        return np.full(slots.shape, 1.0 / max(size, 1))

    def sample(self, n: int, size: int, rng: np.random.Generator, beta: float) -> tuple[np.ndarray, np.ndarray]:
        """n i.i.d. slots of [0, size) -> (int64[n], float32[n] ones); beta is not used."""
        return rng.integers(0, size, n, dtype=np.int64), np.ones(n, np.float32)

    def state_dict(self) -> dict:
        return {}

    def load_state_dict(self, state: dict, size: int) -> None:
        """Nothing to restore."""


class _ProportionalSampling:
    """Proportional sampling over raw priorities p float64[capacity] (eq. 20), with an optional uniform floor u:
    P_u(j) = (1 − u)·P(j) + u/|D|. Subclasses say what p is; by default they take no feedback and rebuild nothing
    (under the permuted control they return their priorities from `recompute`, for the buffer to shuffle)."""

    name = ""

    def __init__(self, args: SamplerArgs):
        self.sampler = PrioritySampler(args.capacity, args.alpha, args.backend)
        self.eps = float(args.eps)
        self.agent, self.permuted = int(args.agent), bool(args.permuted)
        if not (np.isfinite(args.floor) and 0.0 <= args.floor < 1.0):
            raise ValueError(f"floor must lie in [0, 1), got {args.floor!r}")
        self.floor = float(args.floor)
        self.recomputes = self.permuted  # whether `recompute` returns priorities (the buffer then calls it)

    @property
    def priorities(self) -> np.ndarray:
        """float64[capacity] raw priorities (0 on empty slots)."""
        return self.sampler.p

    def initial_priority(self, slots: np.ndarray) -> float:
        """The raw priority new `slots` int64[k] start at."""
        raise NotImplementedError

    def held_mean_priority(self, slots: np.ndarray) -> float:
        """The provisional priority of the rows already held, new `slots` aside (their mean sampling weight,
        `provisional_priority`), until the next recompute sees the new rows' scores; ε_p in an empty buffer."""
        held = self.sampler.p.copy()
        held[slots] = 0.0
        held = held[held > 0]
        return provisional_priority(held, self.sampler.alpha) if held.size else self.eps

    def added(self, slots: np.ndarray) -> None:
        """New slots int64[k] get the initial priority."""
        self.sampler.update(slots, np.full(slots.size, self.initial_priority(slots)))

    def feedback(self, storage: TransitionStorage, agent: int, slots: np.ndarray, generations: np.ndarray,
                 scores: dict[str, np.ndarray]) -> tuple[int, bool]:
        """No feedback asked: (k accepted, no score column changed)."""
        return int(np.size(slots)), False

    def recompute(self, storage: TransitionStorage, lam: float) -> np.ndarray | None:
        """Under the permuted control, the current priorities of the valid rows (the buffer shuffles them);
        else nothing to rebuild."""
        return self.sampler.p[:storage.size].copy() if self.permuted else None

    def set_priorities(self, p: np.ndarray) -> None:
        """Bulk replace: p float64[size] for slots [0, size)."""
        self.sampler.set_all(p)

    def probabilities(self, slots: np.ndarray, size: int) -> np.ndarray:
        """P_u(j) of eq. 20 (with the uniform floor) for valid slots int64[k] -> float64[k]."""
        p = self.sampler.probabilities(slots)
        return p if self.floor == 0 else (1.0 - self.floor) * p + self.floor / max(size, 1)

    def sample(self, n: int, size: int, rng: np.random.Generator, beta: float) -> tuple[np.ndarray, np.ndarray]:
        """n i.i.d. slots from P_u -> (int64[n], IS weights float32[n] = (|D|·P_u)^{−β} / max over the minibatch)."""
        if not (np.isfinite(beta) and beta >= 0):
            raise ValueError(f"beta must be finite and >= 0, got {beta!r}")
        slots = self.sampler.sample(n, rng)
        if self.floor > 0:  # each draw is uniform with probability u (no extra draws without a floor)
            slots = np.where(rng.random(n) < self.floor, rng.integers(0, size, n, dtype=np.int64), slots)
        return slots, importance_weights(self.probabilities(slots, size), size, beta)

    def diagnostics(self) -> dict:
        return {"floor": self.floor}

    def state_dict(self) -> dict:
        """{"alpha", "backend", "priorities": float64[capacity]} (see `PrioritySampler.state_dict`)."""
        return self.sampler.state_dict()

    def load_state_dict(self, state: dict, size: int) -> None:
        """Restore priorities, validated (finite, >= 0, none beyond `size`) before anything changes."""
        staged = PrioritySampler(self.sampler.capacity, self.sampler.alpha, self.sampler.backend)
        staged.load_state_dict(state)
        if np.any(staged.p[size:] != 0):
            raise ValueError(f"sampler priorities on slots beyond size {size}")
        self.sampler = staged


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


class CurriculumSampling(_ProportionalSampling):
    """ACL / CMCL: the curriculum index of eq. 8 over agent `agent`'s score columns, recomputed at each λ.

    From SamplerArgs: eta (CMCL's η; ACL has η = 0), difficulty_source ("difficulty": teachers, "td_abs": ACL
    td_self, whose |δ| arrives as feedback), difficulty_norm, cp_input, lam_max, reversed_difficulty.
    """

    def __init__(self, args: SamplerArgs):
        super().__init__(args)
        if args.difficulty_source not in DIFFICULTY_SOURCES:
            raise ValueError(f"difficulty_source must be in {DIFFICULTY_SOURCES}, got {args.difficulty_source!r}")
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

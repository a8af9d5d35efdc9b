"""The sampling distributions of replay, behind one closed protocol (ALGORITHM.md §3.6, §5, A8, A9, A11).

Where it sits: each rule's file under cmcl/replay/rules/ builds its agents' samplers (`Rule.sampler`, one per
agent, cmcl.system.build_samplers) and `cmcl.replay.buffer.ReplayBuffer` receives them built. The buffer never asks
what kind a sampler is; it calls the protocol on every one of them:

  algorithm, alpha, control, permuted the rule's name, α_s of eq. 20, its sampling control ("none" | "permuted" |
                                      "reversed"), whether the buffer shuffles its recomputed column
  added(slots)                        new slots int64[k] were written (their initial priority)
  feedback(storage, agent, slots, generations, scores) -> (accepted, scores_changed)
                                      the learner's per-row scores of the agent's sampled rows (float[k] each:
                                      "td_abs" |y − Q| and the rule's own, cmcl.replay.rules.contract.LearnerScore)
  has_terms, terms(storage, lam)      whether it has the curriculum's per-row terms, and (when it has) them:
                                      (c_hat, kp, cp, p, scored) float64[size]; p is then its recomputed column
  recompute(storage, lam) -> p | None the raw priority column float64[size] rebuilt from the score columns at λ
                                      (None: nothing to rebuild; `recomputes` says which samplers rebuild); the
                                      buffer applies the permuted control across all returned columns and hands
                                      each back through `set_priorities`
  sample(n, size, rng, beta) -> (slots int64[n], IS weights float32[n])
  probabilities(slots, size) -> float64[k]
  diagnostics() -> dict               scalars for metrics (e.g. PER's running maximum)
  state_dict() / load_state_dict(state, size)

Here: `UniformSampling` (P(j) = 1/|D|, IS weights 1: maddpg's, and the actors' own uniform minibatches) and
`_ProportionalSampling`, the base of every prioritised rule: draws P(j) = p_j^α / Σ_k p_k^α (eq. 20) from a
`cmcl.replay.sampler.PrioritySampler` (cdf or sum tree backend, vectorised), mixed with a uniform floor u when one
is set: P_u(j) = (1 − u)·P(j) + u/|D|. The rules' own samplers are in their files.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cmcl.replay.priority import provisional_priority
from cmcl.replay.sampler import PrioritySampler, importance_weights
from cmcl.replay.storage import TransitionStorage

DIFFICULTY_SOURCES = ("difficulty", "td_abs")  # "td_abs" = ACL's td_self variant (§5)


@dataclass(frozen=True)
class SamplerArgs:
    """What a sampler is built from (cmcl.system.build_samplers builds one per agent from the config).

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


def control_of(args: SamplerArgs) -> str:
    """The sampling control a sampler is built under (`difficulty_transform`): "permuted", "reversed" or "none"."""
    return "permuted" if args.permuted else "reversed" if args.reversed_difficulty else "none"


class UniformSampling:
    """MADDPG's sampling: every valid slot equally likely, IS weights of 1 (no state)."""

    name = "uniform"  # the sampling distribution's name in the metrics ("sampling.modes")
    recomputes = False  # `recompute` never returns priorities
    permuted = False  # uniform draws carry no priority to shuffle
    has_terms = False  # no curriculum terms

    def __init__(self, args: SamplerArgs | None = None):
        """Nothing to hold but the rule's name and α_s (written in the buffer's state)."""
        self.algorithm = "" if args is None else args.algorithm
        self.alpha = 1.0 if args is None else float(args.alpha)
        self.control = "none" if args is None else control_of(args)

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
    has_terms = False  # the curriculum's per-row terms (cmcl.replay.rules.acl's sampler has them)

    def __init__(self, args: SamplerArgs):
        self.sampler = PrioritySampler(args.capacity, args.alpha, args.backend)
        self.algorithm, self.alpha, self.eps = args.algorithm, float(args.alpha), float(args.eps)
        self.control = control_of(args)
        self.agent, self.permuted = int(args.agent), bool(args.permuted)
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

"""One sampling distribution per algorithm (ALGORITHM.md §3.6, §5, A8, A9, A11), chosen once per agent.

Where it sits: `cmcl.replay.buffer.ReplayBuffer` holds one of these per agent, picked from the agent's algorithm
by `sampling_for` when the buffer is built (as Dopamine has one replay class per sampling distribution). Each
object owns its state (priorities, PER's running maximum) and its `state_dict`; the buffer calls the same four
methods on every one of them: `added` (new slots), `sample`, `probabilities`, `state_dict` / `load_state_dict`.

  maddpg ......... UniformSampling:     P(j) = 1/|D|; IS weights 1.
  per ............ PrioritizedSampling: p = |δ| + ε_p kept incrementally (`update_priorities`); new slots get the
                                        running maximum priority (starts at 1.0), which each update raises.
  acl, cmcl ...... CurriculumSampling:  p = KP(ĉ, λ) [+ η·CP(ρ̂)] + ε_p recomputed from the score columns
                                        (`terms`, eqs. 8, 12, 19); a row not yet scored gets the
                                        mean sampling weight of the scored rows (`provisional_priority`, A11).
Prioritized draws use P(j) = p_j^α / Σ_k p_k^α (eq. 20) from a `cmcl.replay.sampler.PrioritySampler` (cdf or sum
tree backend, vectorised).
"""

from __future__ import annotations

import typing
from typing import Literal

import numpy as np

from cmcl.replay.priority import curriculum_priority, provisional_priority
from cmcl.replay.sampler import PrioritySampler, importance_weights
from cmcl.replay.storage import TransitionStorage

# The four compared algorithms (ALGORITHM.md §5): one code, told apart by the sampling distribution of their replay.
# cmcl.config's `teams.<team>.algorithm` takes its values from here.
AlgorithmName = Literal["maddpg", "per", "acl", "cmcl"]
ALGORITHMS: tuple[str, ...] = typing.get_args(AlgorithmName)
DIFFICULTY_SOURCES = ("difficulty", "td_abs")  # "td_abs" = ACL's td_self variant (§5)


class UniformSampling:
    """MADDPG's sampling: every valid slot equally likely, IS weights of 1 (no state)."""

    name = "uniform"  # the sampling distribution's name in the metrics ("sampling.modes")

    def added(self, slots: np.ndarray) -> None:
        """New slots int64[k] were written: nothing to do."""

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
    """Proportional sampling over raw priorities p float64[capacity] (eq. 20); subclasses say what p is."""

    name = ""

    def __init__(self, capacity: int, alpha: float, backend: str, eps: float):
        self.sampler = PrioritySampler(capacity, alpha, backend)
        self.eps = float(eps)

    @property
    def priorities(self) -> np.ndarray:
        """float64[capacity] raw priorities (0 on empty slots)."""
        return self.sampler.p

    def initial_priority(self, slots: np.ndarray) -> float:
        """The raw priority new `slots` int64[k] start at."""
        raise NotImplementedError

    def added(self, slots: np.ndarray) -> None:
        """New slots int64[k] get the initial priority."""
        self.sampler.update(slots, np.full(slots.size, self.initial_priority(slots)))

    def probabilities(self, slots: np.ndarray, size: int) -> np.ndarray:
        """P(j) of eq. 20 for valid slots int64[k] -> float64[k]."""
        return self.sampler.probabilities(slots)

    def sample(self, n: int, size: int, rng: np.random.Generator, beta: float) -> tuple[np.ndarray, np.ndarray]:
        """n i.i.d. slots from P -> (int64[n], IS weights float32[n] = (|D|·P)^{−β} / max over the minibatch)."""
        if not (np.isfinite(beta) and beta >= 0):
            raise ValueError(f"beta must be finite and >= 0, got {beta!r}")
        slots = self.sampler.sample(n, rng)
        return slots, importance_weights(self.sampler.probabilities(slots), size, beta)

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

    def __init__(self, capacity: int, alpha: float, backend: str, eps: float):
        super().__init__(capacity, alpha, backend, eps)
        self.max_priority = 1.0  # the PER rule: starts at 1.0, raised by every update

    def initial_priority(self, slots: np.ndarray) -> float:
        return self.max_priority

    def update_priorities(self, slots: np.ndarray, td_abs: np.ndarray) -> None:
        """p = |δ| + ε_p for fresh slots int64[k] (td_abs float64[k] >= 0), and raise the running maximum."""
        if slots.size:
            p = td_abs + self.eps
            self.sampler.update(slots, p)
            self.max_priority = max(self.max_priority, float(p.max()))

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

    eta: η (used by "cmcl" only; ACL has η = 0). difficulty_source: "difficulty" (teachers) or "td_abs" (ACL
    td_self). difficulty_norm: "rank" | "max" (A1); cp_input: "std" | "raw" (A7); reversed_difficulty: the
    anti-curriculum control (ĉ -> 1 − ĉ); lam_max: cap on λ.
    """

    def __init__(self, capacity: int, alpha: float, backend: str, eps: float, *, algorithm: str, agent: int,
                 eta: float, difficulty_source: str, difficulty_norm: str, cp_input: str, lam_max: float,
                 reversed_difficulty: bool):
        super().__init__(capacity, alpha, backend, eps)
        if difficulty_source not in DIFFICULTY_SOURCES:
            raise ValueError(f"difficulty_source must be in {DIFFICULTY_SOURCES}, got {difficulty_source!r}")
        self.name, self.agent = algorithm, int(agent)
        self.eta = float(eta) if algorithm == "cmcl" else 0.0
        self.difficulty_source, self.difficulty_norm, self.cp_input = difficulty_source, difficulty_norm, cp_input
        self.lam_max, self.reversed_difficulty = float(lam_max), bool(reversed_difficulty)

    def initial_priority(self, slots: np.ndarray) -> float:
        """The provisional priority of the rows already held, new `slots` aside (their mean sampling weight,
        `provisional_priority`), until the next recompute sees the new rows' scores; ε_p in an empty buffer."""
        held = self.sampler.p.copy()
        held[slots] = 0.0
        held = held[held > 0]
        return provisional_priority(held, self.sampler.alpha) if held.size else self.eps

    def terms(self, storage: TransitionStorage, lam: float) -> tuple[np.ndarray, ...]:
        """(c_hat, kp, cp, p, has_difficulty) float64[size] (bool for the last) of this agent over the valid rows
        at λ, from its score columns (`cmcl.replay.priority.curriculum_priority`); read-only."""
        size, a, col = storage.size, self.agent, self.difficulty_source
        return curriculum_priority(storage.scores[col][:size, a], storage.scored[col][:size, a],
                                   storage.scores["curiosity"][:size, a], storage.scored["curiosity"][:size, a],
                                   lam, self.eta, eps=self.eps, difficulty_norm=self.difficulty_norm,
                                   cp_input=self.cp_input, lam_max=self.lam_max,
                                   reversed_difficulty=self.reversed_difficulty, alpha=self.sampler.alpha)

    def set_priorities(self, p: np.ndarray) -> None:
        """Bulk replace: p float64[size] for slots [0, size)."""
        self.sampler.set_all(p)


Sampling = UniformSampling | PrioritizedSampling | CurriculumSampling


def sampling_for(algorithm: str, agent: int, *, capacity: int, alpha: float, backend: str, eps: float, eta: float,
                 difficulty_source: str, difficulty_norm: str, cp_input: str, lam_max: float,
                 reversed_difficulty: bool) -> Sampling:
    """The sampling distribution of one agent learning with `algorithm` (one of ALGORITHMS)."""
    if algorithm == "maddpg":
        return UniformSampling()
    if algorithm == "per":
        return PrioritizedSampling(capacity, alpha, backend, eps)
    if algorithm in ("acl", "cmcl"):
        return CurriculumSampling(capacity, alpha, backend, eps, algorithm=algorithm, agent=agent, eta=eta,
                                  difficulty_source=difficulty_source, difficulty_norm=difficulty_norm,
                                  cp_input=cp_input, lam_max=lam_max, reversed_difficulty=reversed_difficulty)
    raise ValueError(f"algorithm must be one of {ALGORITHMS}, got {algorithm!r}")


def sampling_name(algorithm: str) -> str:
    """The `name` of the sampling distribution `sampling_for(algorithm, ...)` builds ("uniform", "per", "acl",
    "cmcl": the metrics' "sampling.modes"), without building it."""
    if algorithm not in ALGORITHMS:
        raise ValueError(f"algorithm must be one of {ALGORITHMS}, got {algorithm!r}")
    return {"maddpg": UniformSampling.name, "per": PrioritizedSampling.name}.get(algorithm, algorithm)

"""Replay buffer: joint-transition storage plus one sampling distribution per agent (ALGORITHM.md §3.1, §3.6, §5,
A9, A11).

Where it sits in the flow: the replay server owns one `ReplayBuffer`. Rollouts `add` chunks; teachers / ICM
return scores through `update_scores`, the learner its per-row scores through `feedback`; after λ or scores
change, `recompute_priorities(lam)` rebuilds the priority column of every agent whose sampler recomputes, in bulk;
the learner's minibatches are drawn by `sample(agent, S, rng)` per agent.

`ReplayBuffer(storage, samplers)`: the samplers arrive built, one per agent, by each agent's rule
(cmcl.system.build_samplers, from a config validated at load); the buffer only calls the sampler protocol of
`cmcl.replay.sampling` on them, never builds them, asks their kind, or checks their settings again.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence

import numpy as np

from cmcl.replay.priority import LAM_MAX, kfold_priority, permute_priorities
from cmcl.replay.snapshot import STATE_FORMAT, OlderRunError, older_run, require_format, rng_state, set_rng_state
from cmcl.replay.storage import TransitionStorage


class ReplayNotReady(RuntimeError):
    """Sampling was requested before the buffer holds `min_size` transitions."""


class ReplayBuffer:
    """Storage + one sampling distribution per agent.

    Args:
        storage: the transition storage (`cmcl.replay.storage.TransitionStorage`, empty or loaded).
        samplers: one built sampler per agent of the storage (the protocol of cmcl.replay.sampling), in agent order.
        min_size: transitions required before `sample` works (e.g. 3840 warm-up). lam_max: cap on λ.
        control_seed: seeds `control_rng`, the permuted control's generator (carried in `state_dict`, so a resumed
            run draws the same permutations): it shuffles the recomputed column of every sampler whose `permuted`
            is set across the valid rows (`cmcl.replay.priority.permute_priorities`, all permuted columns in one
            draw), and draws the orders in which the agents picking among candidates under the control read their
            candidates' |δ| (`cmcl.replay.buffer_steps.sample_owner_batches`).
    """

    def __init__(self, storage: TransitionStorage, samplers: Sequence, *, min_size: int = 1,
                 lam_max: float = LAM_MAX, control_seed: int | np.random.SeedSequence = 0) -> None:
        self.storage = storage
        self.sampling = list(samplers)
        self.control_rng = np.random.default_rng(control_seed)
        self.min_size, self.lam_max = int(min_size), float(lam_max)
        self.lam: float | None = None  # λ of the last recompute
        self._index_recomputing()

    def _index_recomputing(self) -> None:
        """The agents whose sampler recomputes its priorities (`recomputes`), and those among them that also give
        the curriculum's per-row terms (`has_terms`: ACL / CMCL, for the diagnostics)."""
        self.recomputing = [(a, s) for a, s in enumerate(self.sampling) if s.recomputes]
        self.curriculum = [(a, s) for a, s in self.recomputing if s.has_terms]

    @property
    def algorithms(self) -> list[str]:
        """Each agent's rule name, as its sampler says (written in the state)."""
        return [s.algorithm for s in self.sampling]

    @property
    def alpha(self) -> list[float]:
        """α_s of eq. 20 per agent, as its sampler holds it."""
        return [s.alpha for s in self.sampling]

    @property
    def difficulty_transform(self) -> list[str]:
        """Each agent's sampling control ("none" | "permuted" | "reversed"), as its sampler was built."""
        return [s.control for s in self.sampling]

    @property
    def recomputes(self) -> bool:
        """Whether `recompute_priorities` has anything to rebuild (the runners call it before each update)."""
        return bool(self.recomputing)

    # ------------------------------------------------------------------ storage passthrough
    @property
    def size(self) -> int:
        """Valid transitions |D|."""
        return self.storage.size

    @property
    def capacity(self) -> int:
        return self.storage.capacity

    @property
    def n_agents(self) -> int:
        return self.storage.n_agents

    def add(self, obs, act, rew, next_obs, done, episode, policy_version=0, present=None) -> np.ndarray:
        """Append T transitions (see `TransitionStorage.add`; `present` marks the agents of rows carried from fewer
        agents) -> int64[T] slots (−1 = self-overwritten).

        Each sampler gives the new slots its initial priority (`added`).
        """
        slots = self.storage.add(obs, act, rew, next_obs, done, episode, policy_version, present)
        written = slots[slots >= 0]
        if written.size:
            for sampling in self.sampling:
                sampling.added(written)
        return slots

    def update_scores(self, column: str, slots, generations, values, agents=None) -> int:
        """Write score column values for fresh (slot, generation) pairs -> accepted count (see storage).

        Scores only enter the priorities at the next `recompute_priorities`; feedback-driven rules (PER, ReLo)
        change only through `feedback`.
        """
        return self.storage.update_scores(column, slots, generations, values, agents)

    def get(self, slots) -> dict:
        """Transition rows of valid slots (see `TransitionStorage.get`)."""
        return self.storage.get(slots)

    def valid_slots(self) -> np.ndarray:
        """int64[size]."""
        return self.storage.valid_slots()

    def fold_slots(self, k: int) -> np.ndarray:
        """int64[·] valid slots of fold k."""
        return self.storage.fold_slots(k)

    def generations(self, slots) -> np.ndarray:
        """int64[k] current generation of valid slots (to send along with work on them)."""
        return self.storage.generation[self.storage.check_slots(slots)]

    # ------------------------------------------------------------------ priorities
    def feedback(self, agent: int, slots, generations, scores: dict[str, np.ndarray]) -> tuple[int, bool]:
        """The learner's per-row scores of one agent's sampled rows, to that agent's sampler (`feedback`).

        Args: agent index; slots int[M]; generations int[M] (stale pairs are dropped); scores {name: float[M]}:
        "td_abs" and the rule's own learner scores (checked at the message boundary,
        cmcl.replay.messages.check_feedback), passed on as float64 magnitudes. Returns (accepted count, whether a score
        column changed, i.e. a recompute is due).
        """
        s = self.storage.check_slots(slots)
        gens = np.asarray(generations, dtype=np.int64).reshape(-1)
        clean = {name: np.abs(np.asarray(values, dtype=np.float64)).reshape(-1) for name, values in scores.items()}
        return self.sampling[agent].feedback(self.storage, int(agent), s, gens, clean)

    def update_priorities(self, agent: int, slots, td_abs, generations=None) -> int:
        """|δ| feedback of one agent (PER's rule: p = |δ| + ε_p, the running maximum raised); generations None =
        no staleness check. Returns the accepted count (see `feedback`)."""
        s = self.storage.check_slots(slots)
        gens = self.storage.generation[s] if generations is None else generations
        return self.feedback(agent, s, gens, {"td_abs": td_abs})[0]

    def recompute_priorities(self, lam: float, details: bool = False, apply: bool = True) -> dict | None:
        """Rebuild the priorities of every agent whose sampler recomputes, at curriculum factor `lam`.

        ACL / CMCL: p = KP(ĉ, λ) + η·CP(ρ̂) + ε_p over the valid rows (η = 0 for ACL); unscored rows get the scored
        rows' mean sampling weight (`cmcl.replay.priority.provisional_priority`); other rules: their own column
        (`recompute`). Under the "reversed" control ĉ is 1 − ĉ; under "permuted" the recomputed column of every agent
        with that control is shuffled across the valid rows after it is computed (one draw from `control_rng` per
        recompute for all of them).
        Args: lam in (0, lam_max]; details: also return the curriculum's per-row terms; apply: False computes the
        terms only (read-only: the samplers, λ and the permuted control's generator are left as they are, and
        "priority" is the unpermuted one), for diagnostics that must not change the run.
        Returns: None, or {"agents": int64[A'], "c_hat", "kp", "cp", "priority": float64[size, A'],
        "scored": bool[size, A']} for the A' agents whose sampler has curriculum terms (`has_terms`: ACL / CMCL;
        "priority" is what the samplers hold, permuted under the permuted control; c_hat and kp are the rows' own).
        """
        kfold_priority(0.0, lam, self.lam_max)  # validates lam before anything changes
        size = self.storage.size
        agents = [a for a, _ in self.curriculum]
        terms = [sampling.terms(self.storage, lam) for _, sampling in self.curriculum]  # vectorised per agent
        out = {key: np.stack([t[i] for t in terms], axis=1) if terms else np.zeros((size, 0), bool if i == 4 else float)
               for i, key in enumerate(("c_hat", "kp", "cp", "priority", "scored"))}
        out["agents"] = np.asarray(agents, dtype=np.int64)
        if not apply:
            return out
        # the columns from curriculum terms first, then every other recomputing sampler's
        columns = [(a, s, out["priority"][:, i]) for i, (a, s) in enumerate(self.curriculum)]
        columns += [(a, s, p) for a, s in self.recomputing if not s.has_terms
                    and (p := s.recompute(self.storage, lam)) is not None]
        if columns:
            priority = np.stack([p for _, _, p in columns], axis=1)
            shuffled = [i for i, (_, sampling, _) in enumerate(columns) if sampling.permuted]
            if len(shuffled) == len(columns):
                priority = permute_priorities(priority, self.control_rng)
            elif shuffled:
                priority[:, shuffled] = permute_priorities(priority[:, shuffled], self.control_rng)
            for i, (_, sampling, _) in enumerate(columns):
                sampling.set_priorities(priority[:, i])
            out["priority"] = priority[:, :len(self.curriculum)]
        self.lam = float(lam)
        return out if details else None

    def sampling_distribution(self) -> np.ndarray:
        """P_v(j) of every agent over the valid rows as the samplers hold it now (eq. 20; uniform agents 1/|D|):
        float64[size, N], columns summing to 1 (all zeros for an empty buffer)."""
        size = self.storage.size
        out = np.full((size, self.n_agents), 1.0 / max(size, 1))
        for a, sampling in enumerate(self.sampling):
            if size:
                out[:, a] = sampling.probabilities(np.arange(size), size)
        return out

    def probabilities(self, agent: int, slots) -> np.ndarray:
        """P_v(j) for valid slots int[k] -> float64[k]."""
        return self.sampling[agent].probabilities(self.storage.check_slots(slots), self.storage.size)

    # ------------------------------------------------------------------ sampling
    def sample(self, agent: int, batch_size: int, rng: np.random.Generator,
               beta: float) -> tuple[np.ndarray, np.ndarray]:
        """Draw `batch_size` i.i.d. slots for one agent from its own distribution.

        Returns (slots int64[S], is_weights float32[S]); weights are (|D|·P)^{−β}/max over the minibatch,
        all ones for uniform agents or β = 0 (β_IS: the runners pass their annealed value, ALGORITHM.md §3.7).
        Raises ReplayNotReady below `min_size` transitions.
        """
        size = self.storage.size
        if size < self.min_size:
            raise ReplayNotReady(f"replay holds {size} transitions; sampling needs at least {self.min_size}")
        return self.sampling[agent].sample(int(batch_size), size, rng, float(beta))

    def sample_all(self, batch_size: int, rngs, beta) -> tuple[np.ndarray, np.ndarray]:
        """Every agent draws its own minibatch: rngs is one Generator or one per agent.

        Returns (slots int64[N, S], is_weights float32[N, S]). beta: β_IS, scalar or per agent.
        """
        n = self.storage.n_agents
        gens = list(rngs) if isinstance(rngs, Sequence) else [rngs] * n
        betas = list(beta) if isinstance(beta, Sequence | np.ndarray) else [beta] * n
        pairs = [self.sample(a, batch_size, gens[a], betas[a]) for a in range(n)]
        return np.stack([p[0] for p in pairs]), np.stack([p[1] for p in pairs])

    # ------------------------------------------------------------------ state
    def state_dict(self) -> dict:
        """Nested dict of numpy arrays, plain scalars and strings (codec-ready), format `STATE_FORMAT`.

        Keys: "format", "storage" (see `TransitionStorage.state_dict`), "lam" (float, −1.0 = never recomputed),
        "algorithms" {str(agent): algorithm}, "sampling" {str(agent): that agent's sampling distribution's state},
        "alpha" [float] * N, "difficulty_transform" [str] * N and "control_rng" (the permuted control's PCG64 state,
        its 128-bit integers as decimal strings for msgpack).
        """
        return {
            "format": STATE_FORMAT, "storage": self.storage.state_dict(),
            "lam": -1.0 if self.lam is None else self.lam,
            "algorithms": {str(a): algo for a, algo in enumerate(self.algorithms)},
            "sampling": {str(a): s.state_dict() for a, s in enumerate(self.sampling)},
            "alpha": list(self.alpha), "difficulty_transform": self.difficulty_transform,
            "control_rng": rng_state(self.control_rng),
        }

    def load_state_dict(self, state: dict) -> None:
        """Restore from `state_dict()` output (an older format is refused: `cmcl.replay.snapshot.require_format`);
        everything is validated before anything changes (a snapshot is a file read back). Algorithms, alpha and the
        controls must equal this buffer's samplers' (they come from the run config); each sampler checks its own
        state."""
        n = self.storage.n_agents
        require_format(state, "storage", "lam", "algorithms", "sampling", "alpha", "difficulty_transform",
                       "control_rng")
        algorithms = [state["algorithms"].get(str(a)) for a in range(n)]
        if algorithms != self.algorithms:
            raise ValueError(f"algorithms in state {algorithms} differ from this buffer's {self.algorithms}")
        if [float(a) for a in state["alpha"]] != self.alpha:
            raise ValueError(f"alpha in state ({state['alpha']!r}) differs from this buffer ({self.alpha!r})")
        if list(state["difficulty_transform"]) != self.difficulty_transform:
            raise ValueError(f"difficulty_transform in state ({state['difficulty_transform']!r}) differs from this "
                             f"buffer ({self.difficulty_transform!r})")
        control_rng = np.random.default_rng()
        set_rng_state(control_rng, state["control_rng"])
        staged = TransitionStorage(capacity=self.capacity, n_agents=n, obs_dim=self.storage.obs_dim,
                                   act_dim=self.storage.act_dim, n_folds=self.storage.n_folds)
        try:
            staged.load_state_dict(state["storage"])
        except KeyError as err:
            raise OlderRunError(older_run(f"replay snapshot without storage.{err.args[0]}")) from None
        lam = float(state["lam"])
        if lam != -1.0 and not 0.0 < lam <= self.lam_max:
            raise ValueError(f"lam in state must be -1 (never recomputed) or in (0, {self.lam_max}], got {lam!r}")
        sampling = copy.deepcopy(self.sampling)  # loaded into copies: nothing changes on ValueError
        for a, s in enumerate(sampling):
            try:
                s.load_state_dict(state["sampling"].get(str(a), {}), staged.size)
            except (KeyError, ValueError) as err:
                raise ValueError(f"sampling state of agent {a}: {err}") from err
        self.storage, self.sampling = staged, sampling
        self._index_recomputing()
        self.lam = None if lam < 0 else lam
        self.control_rng = control_rng

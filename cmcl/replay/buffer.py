"""Replay buffer: joint-transition storage plus one sampler per agent (ALGORITHM.md §3.1, §3.6, §5, A9, A11).

Where it sits in the flow: the inline loop (or the replay server actor) owns one `ReplayBuffer`. Rollouts
`add` chunks; teachers / ICM / learner return scores through `update_scores` (and PER's |δ| through
`update_priorities`); after λ or scores change, `recompute_priorities(lam)` rebuilds every ACL/CMCL agent's
priority column in bulk; the learner calls `sample(agent, S, rng)` per agent.

Agent modes (per agent, §5): "uniform" (alias "maddpg"), "per", "acl", "cmcl".
  * uniform: slots drawn uniformly from [0, size); IS weights are ones.
  * per: p = |δ| + ε_p kept incrementally; new slots get the tracked maximum priority (starts at 1.0) and
    `update_priorities` raises that maximum.
  * acl / cmcl: p = KP(ĉ, λ) [+ η·CP(ρ̂)] + ε_p recomputed from the score columns. ĉ and ρ̂ are normalised
    over the rows scored so far; a row without a difficulty score (just written, not yet scored) gets the
    floor ε_p, a row without a curiosity score contributes CP = 0. Newly added slots sit at ε_p until the
    next recompute (A11: score at insertion, then recompute).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cmcl.replay.priority import (
    CURRICULUM_MODES,
    DIFFICULTY_TRANSFORMS,
    EPS_P,
    LAM_MAX,
    canonical_algorithm,
    curriculum_priority,
    kfold_priority,
    permute_priorities,
)
from cmcl.replay.sampler import BACKENDS, PrioritySampler, importance_weights
from cmcl.replay.storage import TransitionStorage

DIFFICULTY_SOURCES = ("difficulty", "td_abs")  # "td_abs" = ACL's td_self variant (§5)


class ReplayNotReady(RuntimeError):
    """Sampling was requested before the buffer holds `min_size` transitions."""


def _per_agent(name: str, value, n: int) -> list:
    """Broadcast a scalar (or validate a length-n sequence) to a list of n values."""
    if isinstance(value, str) or not isinstance(value, Sequence | np.ndarray):
        return [value] * n
    vals = list(value)
    if len(vals) != n:
        raise ValueError(f"{name} must be a scalar or have one entry per agent ({n}), got {len(vals)}")
    return vals


class ReplayBuffer:
    """Storage + per-agent samplers.

    Args:
        capacity, n_agents, obs_dim, act_dim, n_folds: storage layout (see `cmcl.replay.storage`).
        modes: one mode for all agents or one per agent ("uniform"/"maddpg", "per", "acl", "cmcl").
        alpha: sampling exponent α_s of eq. 20, scalar or per agent (A8: 1 for acl / cmcl, 0.6 for per; the
            config resolves each team's, cmcl.config.TeamConfig.effective_alpha). eps: priority floor ε_p.
            backend: "cdf" or "sumtree".
        eta: curiosity weight η (scalar or per agent; used by "cmcl" agents only).
        is_beta: β_IS (scalar or per agent); 0 = IS correction off (weights 1). `sample(beta=...)` overrides.
        difficulty_norm: "rank" (A1, revised) or "max". cp_input: "std" or "raw".
        difficulty_transform: sampling control of the acl / cmcl agents (issue 21): "none"; "reversed" (ĉ -> 1 − ĉ,
            the anti-curriculum); "permuted" (each recompute shuffles every curriculum column across the valid rows,
            `cmcl.replay.priority.permute_priorities`, with a Generator seeded by `control_seed` and carried in
            `state_dict`, so a resumed run draws the same permutations).
        difficulty_source: "difficulty" (teachers) or "td_abs" (ACL td_self), scalar or per agent.
        min_size: transitions required before `sample` works (e.g. 3840 warm-up). lam_max: cap on λ.
    """

    def __init__(self, *, capacity: int = 5000, n_agents: int, obs_dim: int, act_dim: int, n_folds: int = 5,
                 modes="uniform", alpha=1.0, eps: float = EPS_P, backend: str = "cdf", eta=0.5,
                 is_beta=0.0, difficulty_norm: str = "rank", cp_input: str = "std",
                 difficulty_source="difficulty", min_size: int = 1, lam_max: float = LAM_MAX,
                 difficulty_transform: str = "none", control_seed: int | np.random.SeedSequence = 0) -> None:
        self.storage = TransitionStorage(capacity=capacity, n_agents=n_agents, obs_dim=obs_dim,
                                         act_dim=act_dim, n_folds=n_folds)
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
        if not (np.isfinite(eps) and eps > 0):
            raise ValueError(f"eps must be finite and > 0, got {eps!r}")
        if difficulty_norm not in ("max", "rank"):
            raise ValueError(f"difficulty_norm must be 'max' or 'rank', got {difficulty_norm!r}")
        if cp_input not in ("std", "raw"):
            raise ValueError(f"cp_input must be 'std' or 'raw', got {cp_input!r}")
        if int(min_size) != min_size or min_size < 1:
            raise ValueError(f"min_size must be an integer >= 1, got {min_size!r}")
        if difficulty_transform not in DIFFICULTY_TRANSFORMS:
            raise ValueError(f"difficulty_transform must be one of {DIFFICULTY_TRANSFORMS}, "
                             f"got {difficulty_transform!r}")
        alphas = [float(a) for a in _per_agent("alpha", alpha, n_agents)]
        if any(not (np.isfinite(a) and a >= 0) for a in alphas):
            raise ValueError(f"alpha must be finite and >= 0, got {alpha!r}")
        self.alpha: list[float] = alphas  # α_s per agent
        self.eps, self.backend = float(eps), backend
        self.difficulty_transform = difficulty_transform
        self.control_rng = np.random.default_rng(control_seed)  # draws the permuted control's permutations
        self.difficulty_norm, self.cp_input = difficulty_norm, cp_input
        self.min_size, self.lam_max = int(min_size), float(lam_max)
        self.lam: float | None = None  # λ of the last recompute
        n = self.storage.n_agents
        self.modes: list[str] = ["uniform"] * n
        self.eta = [0.0] * n
        self.is_beta = [0.0] * n
        self.difficulty_source = ["difficulty"] * n
        self.max_priority = np.ones(n)  # PER rule: starts at 1.0
        self.samplers: list[PrioritySampler | None] = [None] * n
        self.set_agent_modes(modes, eta=eta, is_beta=is_beta, difficulty_source=difficulty_source)

    # ------------------------------------------------------------------ configuration
    def set_agent_modes(self, modes, eta=None, is_beta=None, difficulty_source=None) -> None:
        """Set each agent's mode (and optionally η, β_IS, difficulty source), all validated first.

        An agent whose mode changes gets a fresh sampler: PER → every valid slot at the current maximum
        priority; ACL/CMCL → every valid slot at ε_p until the next `recompute_priorities`.
        """
        n = self.storage.n_agents
        new_modes = [canonical_algorithm(m) for m in _per_agent("modes", modes, n)]
        new_eta = [float(e) for e in _per_agent("eta", self.eta if eta is None else eta, n)]
        new_beta = [float(b) for b in _per_agent("is_beta", self.is_beta if is_beta is None else is_beta, n)]
        src = self.difficulty_source if difficulty_source is None else difficulty_source
        new_src = _per_agent("difficulty_source", src, n)
        for name, vals in (("eta", new_eta), ("is_beta", new_beta)):
            if any(not (np.isfinite(v) and v >= 0) for v in vals):
                raise ValueError(f"{name} must be finite and >= 0, got {vals}")
        if any(s not in DIFFICULTY_SOURCES for s in new_src):
            raise ValueError(f"difficulty_source must be in {DIFFICULTY_SOURCES}, got {new_src}")
        for a, mode in enumerate(new_modes):
            if mode != self.modes[a] or (mode != "uniform" and self.samplers[a] is None):
                self.samplers[a] = self._fresh_sampler(mode, a)
        self.modes, self.eta, self.is_beta, self.difficulty_source = new_modes, new_eta, new_beta, new_src

    def _fresh_sampler(self, mode: str, agent: int) -> PrioritySampler | None:
        """New sampler for `mode` with every valid slot at its initial priority."""
        if mode == "uniform":
            return None
        sampler = PrioritySampler(self.storage.capacity, self.alpha[agent], self.backend)
        init = self.max_priority[agent] if mode == "per" else self.eps
        sampler.set_all(np.full(self.storage.size, init))
        return sampler

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

    def add(self, obs, act, rew, next_obs, done, episode, policy_version=0) -> np.ndarray:
        """Append T transitions (see `TransitionStorage.add`) -> int64[T] slots (−1 = self-overwritten).

        New slots get the PER maximum priority for "per" agents and ε_p for "acl"/"cmcl" agents.
        """
        slots = self.storage.add(obs, act, rew, next_obs, done, episode, policy_version)
        written = slots[slots >= 0]
        if written.size:
            for a, sampler in enumerate(self.samplers):
                if sampler is not None:
                    init = self.max_priority[a] if self.modes[a] == "per" else self.eps
                    sampler.update(written, np.full(written.size, init))
        return slots

    def update_scores(self, column: str, slots, generations, values, agents=None) -> int:
        """Write score column values for fresh (slot, generation) pairs -> accepted count (see storage).

        Scores only enter ACL/CMCL priorities at the next `recompute_priorities`; PER priorities change only
        through `update_priorities`.
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
    def update_priorities(self, agent: int, slots, td_abs, generations=None) -> int:
        """PER: set p = |δ| + ε_p for fresh slots of a "per" agent and raise its tracked maximum.

        Args: agent index; slots int[M]; td_abs float[M] (finite); generations int[M] or None (no staleness
        check). Also stores |δ| in the td_abs score column. Returns the accepted count.
        """
        self._check_agent(agent)
        if self.modes[agent] != "per":
            raise ValueError(f"update_priorities needs a 'per' agent; agent {agent} is {self.modes[agent]!r}")
        s = self.storage.check_slots(slots)
        gens = self.storage.generation[s] if generations is None else generations
        td = np.abs(np.asarray(td_abs, dtype=np.float64)).reshape(-1)
        if td.shape != s.shape or not np.all(np.isfinite(td)):
            raise ValueError(f"td_abs must be finite with shape {s.shape}, got {np.shape(td_abs)}")
        accepted = self.storage.update_scores("td_abs", s, gens, td.astype(np.float32), agents=[agent])
        ok = self.storage.fresh_mask(s, gens)
        if ok.any():
            p = td[ok] + self.eps
            self.samplers[agent].update(s[ok], p)
            self.max_priority[agent] = max(self.max_priority[agent], float(p.max()))
        return accepted

    def recompute_priorities(self, lam: float, details: bool = False, apply: bool = True) -> dict | None:
        """Rebuild every ACL/CMCL agent's priorities from the score columns at curriculum factor `lam`.

        p = KP(ĉ, λ) + η·CP(ρ̂) + ε_p over the valid rows (η = 0 for ACL); unscored rows get ε_p. Under the
        "reversed" control ĉ is 1 − ĉ; under "permuted" each agent's p column is shuffled across the valid rows
        (one draw from `control_rng` per recompute) after it is computed.
        Args: lam in (0, lam_max]; details: also return the per-row terms; apply: False computes the terms only
        (read-only: the samplers, λ and the permuted control's generator are left as they are, and "priority" is
        the unpermuted one), for diagnostics that must not change the run.
        Returns: None, or {"agents": int64[A'], "c_hat", "kp", "cp", "priority": float64[size, A'],
        "scored": bool[size, A']} for the A' recomputed agents ("priority" is what the samplers hold, permuted
        under the permuted control; c_hat and kp are the rows' own).
        """
        kfold_priority(0.0, lam, self.lam_max)  # validates lam before anything changes
        agents = [a for a, m in enumerate(self.modes) if m in CURRICULUM_MODES]
        size = self.storage.size
        out = {k: [] for k in ("c_hat", "kp", "cp", "priority", "scored")}
        for a in agents:  # one fully vectorised pass over the buffer per agent
            col = self.difficulty_source[a]
            eta = self.eta[a] if self.modes[a] == "cmcl" else 0.0  # ACL: η = 0
            c_hat, kp, cp, p, has_c = curriculum_priority(
                self.storage.scores[col][:size, a], self.storage.scored[col][:size, a],
                self.storage.scores["curiosity"][:size, a], self.storage.scored["curiosity"][:size, a],
                lam, eta, eps=self.eps, difficulty_norm=self.difficulty_norm, cp_input=self.cp_input,
                lam_max=self.lam_max, reversed_difficulty=self.difficulty_transform == "reversed")
            for key, val in zip(out, (c_hat, kp, cp, p, has_c), strict=True):
                out[key].append(val)
        priority = np.stack(out["priority"], axis=1) if agents else np.zeros((size, 0))
        if not apply:
            return {**{k: (np.stack(v, axis=1) if v else np.zeros((size, 0))) for k, v in out.items()},
                    "scored": np.stack(out["scored"], axis=1).astype(bool) if agents else np.zeros((size, 0), bool),
                    "agents": np.asarray(agents, dtype=np.int64)}
        if self.difficulty_transform == "permuted" and agents:
            priority = permute_priorities(priority, self.control_rng)
        for i, a in enumerate(agents):
            self.samplers[a].set_all(priority[:, i])
        self.lam = float(lam)
        if not details:
            return None
        res = {k: (np.stack(v, axis=1) if v else np.zeros((size, 0))) for k, v in out.items()}
        res["priority"] = priority
        res["scored"] = res["scored"].astype(bool)
        res["agents"] = np.asarray(agents, dtype=np.int64)
        return res

    def sampling_distribution(self) -> np.ndarray:
        """P_v(j) of every agent over the valid rows as the samplers hold it now (eq. 20; uniform agents 1/|D|):
        float64[size, N], columns summing to 1 (all zeros for an empty buffer)."""
        size = self.storage.size
        out = np.full((size, self.n_agents), 1.0 / max(size, 1))
        for a, sampler in enumerate(self.samplers):
            if sampler is not None and size:
                out[:, a] = sampler.probabilities(np.arange(size))
        return out

    def probabilities(self, agent: int, slots) -> np.ndarray:
        """P_v(j) for valid slots int[k] -> float64[k]."""
        self._check_agent(agent)
        s = self.storage.check_slots(slots)
        sampler = self.samplers[agent]
        if sampler is None:
            return np.full(s.shape, 1.0 / max(self.storage.size, 1))
        return sampler.probabilities(s)

    # ------------------------------------------------------------------ sampling
    def _check_agent(self, agent: int) -> None:
        if int(agent) != agent or not 0 <= agent < self.storage.n_agents:
            raise ValueError(f"agent must be an index in [0, {self.storage.n_agents}), got {agent!r}")

    def sample(self, agent: int, batch_size: int, rng: np.random.Generator,
               beta: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Draw `batch_size` i.i.d. slots for one agent from its own distribution.

        Returns (slots int64[S], is_weights float32[S]); weights are (|D|·P)^{−β}/max over the minibatch,
        all ones for uniform agents or β = 0 (β defaults to the agent's is_beta).
        Raises ReplayNotReady below `min_size` transitions.
        """
        self._check_agent(agent)
        if int(batch_size) != batch_size or batch_size < 1:
            raise ValueError(f"batch_size must be an integer >= 1, got {batch_size!r}")
        size = self.storage.size
        if size < self.min_size:
            raise ReplayNotReady(f"replay holds {size} transitions; sampling needs at least {self.min_size}")
        sampler = self.samplers[agent]
        if sampler is None:
            return rng.integers(0, size, int(batch_size), dtype=np.int64), np.ones(int(batch_size), np.float32)
        b = self.is_beta[agent] if beta is None else float(beta)
        if not (np.isfinite(b) and b >= 0):
            raise ValueError(f"beta must be finite and >= 0, got {beta!r}")
        slots = sampler.sample(int(batch_size), rng)
        return slots, importance_weights(sampler.probabilities(slots), size, b)

    def sample_all(self, batch_size: int, rngs, beta=None) -> tuple[np.ndarray, np.ndarray]:
        """Every agent draws its own minibatch: rngs is one Generator or one per agent.

        Returns (slots int64[N, S], is_weights float32[N, S]). beta: None, scalar or per agent.
        """
        n = self.storage.n_agents
        gens = _per_agent("rngs", rngs, n) if isinstance(rngs, Sequence) else [rngs] * n
        betas = _per_agent("beta", beta, n)
        pairs = [self.sample(a, batch_size, gens[a], betas[a]) for a in range(n)]
        return np.stack([p[0] for p in pairs]), np.stack([p[1] for p in pairs])

    # ------------------------------------------------------------------ state
    def state_dict(self) -> dict:
        """Nested dict of numpy arrays, plain scalars and strings (codec-ready).

        Keys: "storage" (see `TransitionStorage.state_dict`), "lam" (float, −1.0 = never recomputed),
        "max_priority" float64[N], "modes" {str(agent): mode}, "samplers" {str(agent): sampler state}
        for prioritized agents, plus "alpha" [float] * N, "eps", "backend", "difficulty_transform" and
        "control_rng" (the permuted control's PCG64 state, its 128-bit integers as decimal strings for msgpack).
        """
        return {
            "storage": self.storage.state_dict(),
            "lam": -1.0 if self.lam is None else self.lam,
            "max_priority": self.max_priority.copy(),
            "modes": {str(a): m for a, m in enumerate(self.modes)},
            "samplers": {str(a): s.state_dict() for a, s in enumerate(self.samplers) if s is not None},
            "alpha": list(self.alpha), "eps": self.eps, "backend": self.backend,
            "difficulty_transform": self.difficulty_transform, "control_rng": _rng_state(self.control_rng),
        }

    def load_state_dict(self, state: dict) -> None:
        """Restore from `state_dict()` output; everything is validated before anything changes.

        Modes, alpha and eps must equal this buffer's (they come from the run config).
        """
        n = self.storage.n_agents
        modes = [state["modes"].get(str(a)) for a in range(n)]
        if modes != self.modes:
            raise ValueError(f"modes in state {modes} differ from this buffer's {self.modes}")
        alphas = [float(a) for a in _per_agent("alpha in state", state["alpha"], n)]  # older snapshots: one float
        if alphas != self.alpha:
            raise ValueError(f"alpha in state ({state['alpha']!r}) differs from this buffer ({self.alpha!r})")
        if float(state["eps"]) != self.eps:
            raise ValueError(f"eps in state ({state['eps']!r}) differs from this buffer ({self.eps!r})")
        transform = state.get("difficulty_transform", "none")
        if transform != self.difficulty_transform:
            raise ValueError(f"difficulty_transform in state ({transform!r}) differs from this buffer "
                             f"({self.difficulty_transform!r})")
        control_rng = np.random.default_rng()
        if "control_rng" in state:
            _set_rng_state(control_rng, state["control_rng"])
        maxp = np.asarray(state["max_priority"], dtype=np.float64)
        if maxp.shape != (n,) or not np.all(np.isfinite(maxp)) or np.any(maxp <= 0):
            raise ValueError(f"max_priority must be finite, > 0, shape ({n},); got {maxp!r}")
        staged = TransitionStorage(capacity=self.capacity, n_agents=n, obs_dim=self.storage.obs_dim,
                                   act_dim=self.storage.act_dim, n_folds=self.storage.n_folds)
        staged.load_state_dict(state["storage"])
        samplers: list[PrioritySampler | None] = [None] * n
        for a in range(n):
            if self.modes[a] != "uniform":
                samplers[a] = PrioritySampler(self.capacity, self.alpha[a], self.backend)
                samplers[a].load_state_dict(state["samplers"][str(a)])
                if np.any(samplers[a].p[staged.size:] != 0):
                    raise ValueError(f"sampler {a} has priorities on slots beyond size {staged.size}")
        lam = float(state["lam"])
        if lam != -1.0 and not 0.0 < lam <= self.lam_max:
            raise ValueError(f"lam in state must be -1 (never recomputed) or in (0, {self.lam_max}], got {lam!r}")
        self.storage, self.samplers, self.max_priority = staged, samplers, maxp.copy()
        self.lam = None if lam < 0 else lam
        if "control_rng" in state:
            self.control_rng = control_rng


def _rng_state(rng: np.random.Generator) -> dict:
    """A PCG64 Generator's state with its 128-bit integers as decimal strings (msgpack holds at most 64 bits)."""
    st = rng.bit_generator.state
    return {"bit_generator": st["bit_generator"], "state": str(st["state"]["state"]), "inc": str(st["state"]["inc"]),
            "has_uint32": int(st["has_uint32"]), "uinteger": int(st["uinteger"])}


def _set_rng_state(rng: np.random.Generator, state: dict) -> None:
    """Inverse of `_rng_state` (ValueError for another bit generator or malformed numbers)."""
    if state.get("bit_generator") != "PCG64":
        raise ValueError(f"control_rng must be a PCG64 state, got {state.get('bit_generator')!r}")
    rng.bit_generator.state = {"bit_generator": "PCG64",
                               "state": {"state": int(state["state"]), "inc": int(state["inc"])},
                               "has_uint32": int(state["has_uint32"]), "uinteger": int(state["uinteger"])}


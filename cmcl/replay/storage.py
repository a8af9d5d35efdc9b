"""Ring storage of joint multi-agent transitions plus per-agent score columns (ALGORITHM.md §3.1, §3.9).

Where it sits in the flow: `cmcl.replay.buffer.ReplayBuffer` wraps one `TransitionStorage` and adds the per-agent
samplers. Rollouts append chunks with `add`; teachers, the ICM and the learner write scores back with
`update_scores`, identified by (slot, generation) so that results for overwritten slots are dropped.

Layout (cap = capacity, N agents):
    obs, next_obs  float32[cap, N, obs_dim]      act  float32[cap, N, act_dim]
    rew            float32[cap, N]               done float32[cap, N] (per agent: no bootstrap for that agent)
    id             int64[cap]  global insertion counter (slot = id mod cap)
    episode        int64[cap]  episode index given by the writer
    fold           int64[cap]  episode mod K, fixed at write (all of an episode's transitions share a fold)
    generation     int64[cap]  0 = never written, +1 on every write of the slot
    policy_version int64[cap]
    scores[col]    float32[cap, N] for col in SCORE_COLUMNS; scored[col] bool[cap, N] (reset on overwrite)
    present        bool[cap, N]  the agents the row holds: all True, except rows carried from a run with fewer agents
                   (run.carry_replay, cmcl.replay.agent_padding): the first n agents present, the others absent
                   (observation, action, reward and done 0), always a prefix. `absent_rows` counts the valid rows
                   with an absent agent; a snapshot holds the column only when some row has one.
Slots [0, size) are valid; the ring fills from slot 0 and wraps once full.
"""

from __future__ import annotations

import numpy as np

SCORE_COLUMNS = ("difficulty", "curiosity", "td_abs")
_F32_MAX = float(np.finfo(np.float32).max)
_META = ("id", "episode", "fold", "generation", "policy_version")


def _real_array(name: str, x, shape: tuple) -> np.ndarray:
    """Validate a real numeric array of exactly `shape` with finite float32-representable values -> float32."""
    arr = np.asarray(x)
    if arr.dtype.kind not in "fiu":
        raise ValueError(f"{name} must be a real numeric array, got dtype {arr.dtype}")
    if arr.shape != shape:
        raise ValueError(f"{name} has shape {arr.shape}, expected {shape}")
    if arr.dtype.kind == "f" and arr.size:
        finite = np.isfinite(arr)
        if not finite.all():
            raise ValueError(f"{name} must be finite, got {arr[~finite].ravel()[0]!r}")
        big = np.abs(arr) > _F32_MAX
        if big.any():
            raise ValueError(f"{name} value {arr[big].ravel()[0]!r} does not fit in float32")
    return arr.astype(np.float32)


def _int_array(name: str, x, shape: tuple, low: int = 0) -> np.ndarray:
    """Validate an integer array (scalars broadcast) of `shape` with values >= low -> int64."""
    arr = np.asarray(x)
    if arr.dtype.kind not in "iu":
        raise ValueError(f"{name} must be integers, got dtype {arr.dtype}")
    if arr.ndim == 0:
        arr = np.broadcast_to(arr, shape)
    if arr.shape != shape:
        raise ValueError(f"{name} has shape {arr.shape}, expected {shape}")
    if arr.size and arr.min() < low:
        raise ValueError(f"{name} must be >= {low}, got {arr.min()!r}")
    return arr.astype(np.int64)


class TransitionStorage:
    """FIFO ring of joint transitions with fold ids, generations and per-agent score columns.

    Args:
        capacity: slots B (5000 in the paper). n_agents: N. obs_dim, act_dim: per-agent sizes
            (agents with smaller observations are zero-padded by the writer). n_folds: K >= 1.
    """

    def __init__(self, *, capacity: int = 5000, n_agents: int, obs_dim: int, act_dim: int, n_folds: int = 5) -> None:
        for name, v in (("capacity", capacity), ("n_agents", n_agents), ("obs_dim", obs_dim),
                        ("act_dim", act_dim), ("n_folds", n_folds)):
            if int(v) != v or v < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
        self.capacity, self.n_agents = int(capacity), int(n_agents)
        self.obs_dim, self.act_dim, self.n_folds = int(obs_dim), int(act_dim), int(n_folds)
        cap, n = self.capacity, self.n_agents
        self.obs = np.zeros((cap, n, self.obs_dim), np.float32)
        self.act = np.zeros((cap, n, self.act_dim), np.float32)
        self.rew = np.zeros((cap, n), np.float32)
        self.next_obs = np.zeros((cap, n, self.obs_dim), np.float32)
        self.done = np.zeros((cap, n), np.float32)
        self.id, self.episode, self.fold, self.generation, self.policy_version = (
            np.zeros(cap, np.int64) for _ in _META)
        self.scores = {c: np.zeros((cap, n), np.float32) for c in SCORE_COLUMNS}
        self.scored = {c: np.zeros((cap, n), bool) for c in SCORE_COLUMNS}
        self.present = np.ones((cap, n), bool)
        self.absent_rows = 0
        self.size = 0
        self.next_id = 0
        self.stale_dropped_total = 0
        self.last_dropped = 0

    @property
    def ptr(self) -> int:
        """Next slot to write (= next_id mod capacity)."""
        return self.next_id % self.capacity

    def _as_chunk(self, obs, act, rew, next_obs, done, episode, policy_version) -> dict:
        """The fields in the storage's dtypes; a rollout's chunk was checked at the message boundary
        (cmcl.io.records.check_chunk), so nothing is checked again here."""
        t = np.shape(obs)[0]
        done = np.asarray(done, np.float32)
        return {"obs": np.asarray(obs, np.float32), "act": np.asarray(act, np.float32),
                "rew": np.asarray(rew, np.float32), "next_obs": np.asarray(next_obs, np.float32),
                "done": np.repeat(done[:, None], self.n_agents, axis=1) if done.ndim == 1 else done,
                "episode": np.asarray(episode, np.int64),
                "policy_version": np.broadcast_to(np.asarray(policy_version, np.int64), (t,))}

    def add(self, obs, act, rew, next_obs, done, episode, policy_version=0, present=None) -> np.ndarray:
        """Append T transitions (vectorised); returns int64[T] slots, −1 for the ones a longer-than-capacity
        chunk overwrote itself (only its last `capacity` transitions are kept).

        Args: obs, next_obs [T, N, obs_dim]; act [T, N, act_dim]; rew [T, N]; done [T, N] (or [T]: one per
            row, every agent's) in [0, 1];
            episode int[T] >= 0; policy_version int scalar or int[T] >= 0;
            present bool[T, N], a prefix of present agents per row (None: every agent; module docstring).
        """
        chunk = self._as_chunk(obs, act, rew, next_obs, done, episode, policy_version)
        t = chunk["done"].shape[0]
        chunk["present"] = np.ones((t, self.n_agents), bool) if present is None else self._present(present, t)
        out = np.full(t, -1, np.int64)
        if t == 0:
            return out
        keep = slice(max(0, t - self.capacity), t)
        ids = self.next_id + np.arange(t, dtype=np.int64)[keep]
        slots = ids % self.capacity
        overwritten = slots[slots < self.size]
        self.absent_rows += int((~chunk["present"][keep]).any(1).sum() - (~self.present[overwritten]).any(1).sum())
        for name in ("obs", "act", "rew", "next_obs", "done", "episode", "policy_version", "present"):
            getattr(self, name)[slots] = chunk[name][keep]
        self.id[slots] = ids
        self.fold[slots] = chunk["episode"][keep] % self.n_folds
        self.generation[slots] += 1
        for c in SCORE_COLUMNS:
            self.scores[c][slots] = 0.0
            self.scored[c][slots] = False
        self.next_id += t
        self.size = min(self.capacity, self.size + t)
        out[keep] = slots
        return out

    def check_slots(self, slots, valid_only: bool = True) -> np.ndarray:
        """int64[k] slots; ValueError unless integer and in [0, size) (or [0, capacity))."""
        arr = np.asarray(slots)
        if arr.dtype.kind not in "iu":
            raise ValueError(f"slots must be integers, got dtype {arr.dtype}")
        arr = arr.astype(np.int64).ravel()
        hi = self.size if valid_only else self.capacity
        if arr.size and (arr.min() < 0 or arr.max() >= hi):
            raise ValueError(f"slots must lie in [0, {hi}), got range [{arr.min()}, {arr.max()}]")
        return arr

    def _check_agents(self, agents) -> np.ndarray:
        """int64[A'] distinct agent indices (all agents when None)."""
        if agents is None:
            return np.arange(self.n_agents, dtype=np.int64)
        arr = np.atleast_1d(np.asarray(agents))
        if arr.dtype.kind not in "iu" or arr.ndim != 1:
            raise ValueError(f"agents must be a 1-D integer sequence, got {agents!r}")
        if arr.size == 0 or arr.min() < 0 or arr.max() >= self.n_agents or np.unique(arr).size != arr.size:
            raise ValueError(f"agents must be distinct indices in [0, {self.n_agents}), got {arr.tolist()}")
        return arr.astype(np.int64)

    def fresh_mask(self, slots: np.ndarray, generations) -> np.ndarray:
        """bool[k]: the slot still holds the transition of that generation (written and not overwritten)."""
        gens = _int_array("generations", generations, slots.shape)
        return (self.generation[slots] == gens) & (gens > 0)

    def update_scores(self, column: str, slots, generations, values, agents=None) -> int:
        """Write scores for (slot, generation) pairs; stale pairs are dropped and counted.

        Args:
            column: one of SCORE_COLUMNS. slots int[M] in [0, capacity). generations int[M].
            values: float[M, A'] (A' = len(agents), or N when agents is None); float[M] allowed when A' = 1;
                finite and >= 0.
            agents: agent indices the value columns belong to (None = all N agents).
        Returns:
            number of accepted rows; `last_dropped` holds the dropped count of this call,
            `stale_dropped_total` the running total.
        """
        if column not in SCORE_COLUMNS:
            raise ValueError(f"column must be one of {SCORE_COLUMNS}, got {column!r}")
        s = self.check_slots(slots, valid_only=False)
        ag = self._check_agents(agents)
        vals = np.asarray(values)
        if vals.ndim == 1 and ag.size == 1:
            vals = vals[:, None]
        vals = _real_array("values", vals, (s.size, ag.size))
        if vals.size and vals.min() < 0:
            raise ValueError(f"values must be >= 0, got {vals.min()!r}")
        ok = self.fresh_mask(s, generations)
        rows = s[ok]
        self.scores[column][rows[:, None], ag[None, :]] = vals[ok]
        self.scored[column][rows[:, None], ag[None, :]] = True
        self.last_dropped = int(s.size - rows.size)
        self.stale_dropped_total += self.last_dropped
        return int(rows.size)

    def get(self, slots) -> dict:
        """Rows of valid slots int[S] -> dict: obs/next_obs [S,N,od], act [S,N,ad], rew [S,N], done [S,N],
        present bool[S,N], id/episode/fold/generation/policy_version int64[S] (copies)."""
        s = self.check_slots(slots)
        names = ("obs", "act", "rew", "next_obs", "done", "present") + _META
        return {name: getattr(self, name)[s] for name in names}

    def valid_slots(self) -> np.ndarray:
        """int64[size]: every valid slot."""
        return np.arange(self.size, dtype=np.int64)

    def fold_slots(self, k: int) -> np.ndarray:
        """int64[·]: valid slots of fold k (0 <= k < n_folds)."""
        if int(k) != k or not 0 <= k < self.n_folds:
            raise ValueError(f"k must be a fold index in [0, {self.n_folds}), got {k!r}")
        return np.flatnonzero(self.fold[:self.size] == k).astype(np.int64)

    def fold_counts(self) -> np.ndarray:
        """int64[K]: valid transitions per fold."""
        return np.bincount(self.fold[:self.size], minlength=self.n_folds).astype(np.int64)

    def state_dict(self) -> dict:
        """Numpy arrays (rows [0, size)) and plain ints; see the module docstring for the layout."""
        n = self.size
        out = {"capacity": self.capacity, "n_agents": self.n_agents, "obs_dim": self.obs_dim,
               "act_dim": self.act_dim, "n_folds": self.n_folds, "size": n, "next_id": self.next_id,
               "stale_dropped_total": self.stale_dropped_total}
        for name in ("obs", "act", "rew", "next_obs", "done") + _META:
            out[name] = getattr(self, name)[:n].copy()
        out["scores"] = {c: self.scores[c][:n].copy() for c in SCORE_COLUMNS}
        out["scored"] = {c: self.scored[c][:n].copy() for c in SCORE_COLUMNS}
        if self.absent_rows:
            out["present"] = self.present[:n].copy()
        return out

    def load_state_dict(self, state: dict) -> None:
        """Validate everything, then replace the contents (nothing changes on ValueError)."""
        for key in ("capacity", "n_agents", "obs_dim", "act_dim", "n_folds"):
            if state.get(key) != getattr(self, key):
                mine = getattr(self, key)
                raise ValueError(f"{key} in state ({state.get(key)!r}) differs from this storage ({mine!r})")
        n, next_id = state.get("size"), state.get("next_id")
        ints = isinstance(n, int | np.integer) and isinstance(next_id, int | np.integer)
        if not ints or next_id < 0 or n != min(next_id, self.capacity):
            raise ValueError(f"size {n!r} and next_id {next_id!r} are inconsistent for capacity {self.capacity}")
        na, od, ad = self.n_agents, self.obs_dim, self.act_dim
        new = {"obs": _real_array("obs", state["obs"], (n, na, od)),
               "act": _real_array("act", state["act"], (n, na, ad)),
               "rew": _real_array("rew", state["rew"], (n, na)),
               "next_obs": _real_array("next_obs", state["next_obs"], (n, na, od)),
               "done": _real_array("done", state["done"], (n, na))}
        for name in _META:
            new[name] = _int_array(name, state[name], (n,))
        if n and not np.array_equal(new["id"] % self.capacity, np.arange(n)):
            raise ValueError("id column is inconsistent with slot positions")
        if n and not np.array_equal(new["fold"], new["episode"] % self.n_folds):
            raise ValueError("fold column is inconsistent with episode mod n_folds")
        scores = {c: _real_array(f"scores.{c}", state["scores"][c], (n, na)) for c in SCORE_COLUMNS}
        scored = {}
        for c in SCORE_COLUMNS:
            m = np.asarray(state["scored"][c])
            if m.dtype != bool or m.shape != (n, na):
                raise ValueError(f"scored.{c} must be bool of shape {(n, na)}, got {m.dtype} {m.shape}")
            scored[c] = m
        new["present"] = self._present(state["present"], n) if "present" in state else np.ones((n, na), bool)
        self._reset_rows(n)
        for name, arr in new.items():
            getattr(self, name)[:n] = arr
        for c in SCORE_COLUMNS:
            self.scores[c][:n], self.scored[c][:n] = scores[c], scored[c]
        self.size, self.next_id = int(n), int(next_id)
        self.stale_dropped_total = int(state["stale_dropped_total"])
        self.absent_rows = int((~new["present"]).any(1).sum())

    def _present(self, present, t: int) -> np.ndarray:
        """present bool[t, N] whose every row is a non-empty prefix of agents (module docstring), validated."""
        arr = np.asarray(present)
        if arr.dtype != bool or arr.shape != (t, self.n_agents):
            raise ValueError(f"present must be bool of shape {(t, self.n_agents)}, got {arr.dtype} {arr.shape}")
        prefix = np.arange(self.n_agents) < arr.sum(1, keepdims=True)
        if t and (not arr[:, 0].all() or not np.array_equal(arr, prefix)):
            raise ValueError("present must mark the first n >= 1 agents of every row (a prefix)")
        return arr

    def _reset_rows(self, n: int) -> None:
        """Zero rows [n, capacity) of every column (used on load); `present` there is True."""
        self.present[n:] = True
        for name in ("obs", "act", "rew", "next_obs", "done") + _META:
            getattr(self, name)[n:] = 0
        for c in SCORE_COLUMNS:
            self.scores[c][n:], self.scored[c][n:] = 0.0, False

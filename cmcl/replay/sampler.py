"""Per-agent samplers over replay slots: uniform and proportional prioritized (ALGORITHM.md §3.6, A8, A9).

Where it sits in the flow: `cmcl.replay.buffer.ReplayBuffer` owns one sampler per agent. Priorities arrive in bulk
(a whole column after each λ change) or as a few leaves (PER |δ| updates, newly written slots); agents
draw i.i.d. minibatches with P(j) = p_j^α / Σ_k p_k^α and get importance weights.

Two interchangeable backends for the proportional sampler, both vectorised (no per-leaf Python loop):
  * "cdf":     weights w = p^α in a flat array; a cached cumulative sum (rebuilt lazily after a change,
               O(capacity)) and `searchsorted` for the draws, O(S log capacity).
  * "sumtree": an array-based binary sum tree (leaves at [P, 2P), P = next power of two >= capacity). Bulk
               build level by level (log2 P numpy ops), bulk leaf update by levels over the unique dirty
               parents, draws by a vectorised descent of all S samples at once.
Slots that are empty or have priority 0 are never drawn.
"""

from __future__ import annotations

import numpy as np

BACKENDS = ("cdf", "sumtree")


def _check_slots(slots, capacity: int) -> np.ndarray:
    """int64[k] slot indices, ValueError unless all lie in [0, capacity)."""
    arr = np.asarray(slots)
    if arr.dtype.kind not in "iu":
        raise ValueError(f"slots must be integers, got dtype {arr.dtype}")
    arr = arr.astype(np.int64).ravel()
    if arr.size and (arr.min() < 0 or arr.max() >= capacity):
        raise ValueError(f"slots must lie in [0, {capacity}), got range [{arr.min()}, {arr.max()}]")
    return arr


def _check_priorities(p, shape: tuple) -> np.ndarray:
    """float64 priorities of `shape`, ValueError unless finite and >= 0."""
    arr = np.asarray(p, dtype=np.float64)
    if arr.shape != shape:
        raise ValueError(f"priorities must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ValueError("priorities must be finite and >= 0")
    return arr


def importance_weights(probs, size: int, beta: float) -> np.ndarray:
    """IS weights w_j = (|D|·P(j))^{−β} divided by their maximum over the minibatch.

    Args:
        probs: float[S] sampling probabilities of the drawn slots (all > 0). size: |D|.
        beta: β_IS >= 0; 0 gives all ones.
    Returns:
        float32[S] in (0, 1]; computed in log space so nothing overflows.
    """
    p = np.asarray(probs, dtype=np.float64)
    if beta == 0 or p.size == 0:
        return np.ones(p.shape, dtype=np.float32)
    log_x = np.log(size * p)
    return np.exp(-beta * (log_x - log_x.min())).astype(np.float32)


class _CdfBackend:
    """Weights in a flat array; cumulative sum cached until the next change."""

    def __init__(self, capacity: int) -> None:
        self.w = np.zeros(capacity)  # [capacity] p^α
        self._cdf: np.ndarray | None = None

    def build(self, w: np.ndarray) -> None:
        self.w[:] = w
        self._cdf = None

    def update(self, slots: np.ndarray, w: np.ndarray) -> None:
        self.w[slots] = w
        self._cdf = None

    def leaves(self, slots: np.ndarray) -> np.ndarray:
        return self.w[slots]

    def _cumsum(self) -> np.ndarray:
        if self._cdf is None:
            self._cdf = np.cumsum(self.w)
        return self._cdf

    def total(self) -> float:
        return float(self._cumsum()[-1])

    def draw(self, r: np.ndarray) -> np.ndarray:
        """Slots for uniforms r in [0, 1) (float64[S]) -> int64[S]."""
        cdf = self._cumsum()
        idx = np.searchsorted(cdf, r * cdf[-1], side="right")
        over = idx >= cdf.size  # r·total rounded up to total
        if np.any(over):
            idx[over] = np.flatnonzero(self.w > 0)[-1]
        return idx.astype(np.int64)


class _SumTreeBackend:
    """Array sum tree: node i has children 2i, 2i+1; root at 1; leaves at [P, 2P)."""

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self.P = 1 << max(0, int(capacity - 1).bit_length())
        self.depth = self.P.bit_length() - 1
        self.tree = np.zeros(2 * self.P)

    def build(self, w: np.ndarray) -> None:
        P, t = self.P, self.tree
        t[P:P + self.capacity] = w
        t[P + self.capacity:] = 0.0
        s = P // 2
        while s >= 1:  # one vectorised op per level
            t[s:2 * s] = t[2 * s:4 * s:2] + t[2 * s + 1:4 * s:2]
            s //= 2

    def update(self, slots: np.ndarray, w: np.ndarray) -> None:
        if slots.size == 0:
            return
        if slots.size * self.depth >= self.P:  # cheaper to rebuild everything
            leaves = self.tree[self.P:self.P + self.capacity].copy()
            leaves[slots] = w
            self.build(leaves)
            return
        t = self.tree
        t[self.P + slots] = w
        idx = (self.P + slots) >> 1
        for _ in range(self.depth):  # all dirty nodes of one level at once; a repeated node just
            t[idx] = t[2 * idx] + t[2 * idx + 1]  # gets the same (correct) sum written twice
            idx >>= 1

    def leaves(self, slots: np.ndarray) -> np.ndarray:
        return self.tree[self.P + slots]

    def total(self) -> float:
        return float(self.tree[1])

    def draw(self, r: np.ndarray) -> np.ndarray:
        """Vectorised descent for uniforms r in [0, 1) (float64[S]) -> int64[S] slots."""
        t = self.tree
        u = r * t[1]
        idx = np.ones(r.shape, dtype=np.int64)
        for _ in range(self.depth):
            left = 2 * idx
            lv = t[left]
            right = u >= lv
            u = np.where(right, u - lv, u)
            idx = left + right
        slots = idx - self.P
        bad = (slots >= self.capacity) | (t[idx] <= 0)  # only through floating-point rounding
        if np.any(bad):
            w = t[self.P:self.P + self.capacity]
            cdf = np.cumsum(w)
            fix = np.minimum(np.searchsorted(cdf, r[bad] * cdf[-1], side="right"), np.flatnonzero(w > 0)[-1])
            slots[bad] = fix
        return slots


class PrioritySampler:
    """Proportional prioritized sampler over `capacity` slots (one per agent).

    Args:
        capacity: number of slots. alpha: sampling exponent α_s >= 0. backend: "cdf" or "sumtree".
    Holds raw priorities p (float64[capacity], before the exponent); P(j) = p_j^α / Σ_k p_k^α, where a
    priority of exactly 0 has weight 0 for every α (so α = 0 is uniform over the slots with p > 0).
    """

    def __init__(self, capacity: int, alpha: float = 0.6, backend: str = "cdf") -> None:
        if int(capacity) != capacity or capacity < 1:
            raise ValueError(f"capacity must be an integer >= 1, got {capacity!r}")
        if not (np.isfinite(alpha) and alpha >= 0):
            raise ValueError(f"alpha must be finite and >= 0, got {alpha!r}")
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
        self.capacity = int(capacity)
        self.alpha = float(alpha)
        self.backend = backend
        self.p = np.zeros(self.capacity)  # [capacity] raw priorities
        self._impl = _CdfBackend(self.capacity) if backend == "cdf" else _SumTreeBackend(self.capacity)

    def _pow(self, p: np.ndarray) -> np.ndarray:
        """Leaf weights p^α, with priority 0 mapping to weight 0 for every α (also α = 0)."""
        if self.alpha == 0:
            return (p > 0).astype(np.float64)
        return np.power(p, self.alpha) if self.alpha != 1.0 else p.copy()

    def set_all(self, p) -> None:
        """Bulk replace: p float[M] gives slots [0, M); slots >= M get priority 0 (never drawn)."""
        arr = np.asarray(p, dtype=np.float64).ravel()
        if arr.size > self.capacity:
            raise ValueError(f"got {arr.size} priorities for capacity {self.capacity}")
        arr = _check_priorities(arr, arr.shape)
        self.p[:arr.size] = arr
        self.p[arr.size:] = 0.0
        self._impl.build(self._pow(self.p))

    def update(self, slots, p) -> None:
        """Set raw priorities of some slots: slots int[k], p float[k] (finite, >= 0)."""
        s = _check_slots(slots, self.capacity)
        arr = _check_priorities(np.broadcast_to(np.asarray(p, dtype=np.float64), s.shape), s.shape)
        self.p[s] = arr
        self._impl.update(s, self._pow(arr))

    @property
    def total(self) -> float:
        """Σ_j p_j^α over all slots."""
        return self._impl.total()

    def probabilities(self, slots) -> np.ndarray:
        """P(j) = p_j^α / Σ_k p_k^α (eq. 20) for slots int[k] -> float64[k]."""
        s = _check_slots(slots, self.capacity)
        total = self.total
        return self._impl.leaves(s) / total if total > 0 else np.zeros(s.shape)

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """Draw n i.i.d. slots with probability P(j) (eq. 20) -> int64[n]. ValueError if all priorities are 0."""
        if not self.total > 0:
            raise ValueError("cannot sample: all priorities are 0")
        return self._impl.draw(rng.random(int(n)))

    def state_dict(self) -> dict:
        """{"alpha": float, "backend": str, "priorities": float64[capacity]}."""
        return {"alpha": self.alpha, "backend": self.backend, "priorities": self.p.copy()}

    def load_state_dict(self, state: dict) -> None:
        """Restore raw priorities and rebuild the backend (alpha and backend come from the constructor)."""
        p = _check_priorities(state["priorities"], (self.capacity,))
        if float(state["alpha"]) != self.alpha:
            raise ValueError(f"alpha in state ({state['alpha']!r}) differs from this sampler ({self.alpha!r})")
        self.p[:] = p
        self._impl.build(self._pow(self.p))

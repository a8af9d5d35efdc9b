"""Replay throughput: our vectorised ReplayBuffer vs the classic per-leaf Python sum tree (openai/baselines PER).

Operations, for N = 4 agents at capacity 5k, 100k and 1M:
  sample     every agent draws its own minibatch of 128 with IS weights (β = 0.4), priorities unchanged
  update     every agent sets 128 new PER priorities (|δ| + ε), raising the tracked maximum
  recompute  every agent's priority column rebuilt from its score columns at a new λ (KP + η·CP + ε)
  per_step   PER learner step: update + sample (ours timed as one sequence, so lazy work is charged)
  cmcl_step  CMCL learner step (§3.8 recomputes every step): recompute + sample, timed the same way
Ours runs both backends ("cdf": cumsum + searchsorted; "sumtree": array tree, level-wise bulk updates).
The reference is baselines' SumSegmentTree (a Python loop up the tree per leaf write, a Python descent per
sample); it computes the priority column with the same numpy code, then writes it leaf by leaf. Reference
recomputes that would take seconds are timed on a 20k-leaf slice and extrapolated linearly (marked "~").

Rounds of ours and the reference are interleaved (the machine is shared); medians are reported.
Run: .venv/bin/python bench/replay_throughput.py    (last line: ``ratio: X`` = ours (cdf backend) over
reference, CMCL learner steps per second at capacity 100k)
"""

from __future__ import annotations

import operator
import statistics
import time

import numpy as np

from cmcl.replay.buffer import ReplayBuffer
from cmcl.replay.priority import curiosity_priority, kfold_priority, normalise_curiosity, normalise_difficulty
from cmcl.replay.registry import build_sampler
from cmcl.replay.sampling import SamplerArgs
from cmcl.replay.storage import TransitionStorage

N, S, ALPHA, BETA, EPS, ETA = 4, 128, 0.6, 0.4, 1e-6, 0.5
CAPACITIES = (5_000, 100_000, 1_000_000)
ROUNDS = 5


# ----------------------------------------------------------------------------- reference (baselines-style)
class SumSegmentTree:
    """openai/baselines `SumSegmentTree`: Python list, per-leaf update loop, per-sample prefix-sum descent."""

    def __init__(self, capacity: int) -> None:
        assert capacity > 0 and capacity & (capacity - 1) == 0, "capacity must be a power of 2"
        self._capacity = capacity
        self._value = [0.0] * (2 * capacity)
        self._op = operator.add

    def __setitem__(self, idx: int, val: float) -> None:
        idx += self._capacity
        self._value[idx] = val
        idx //= 2
        while idx >= 1:
            self._value[idx] = self._op(self._value[2 * idx], self._value[2 * idx + 1])
            idx //= 2

    def __getitem__(self, idx: int) -> float:
        return self._value[self._capacity + idx]

    def sum(self) -> float:
        return self._value[1]

    def find_prefixsum_idx(self, prefixsum: float) -> int:
        idx = 1
        while idx < self._capacity:
            if self._value[2 * idx] > prefixsum:
                idx = 2 * idx
            else:
                prefixsum -= self._value[2 * idx]
                idx = 2 * idx + 1
        return idx - self._capacity


class Reference:
    """baselines PrioritizedReplayBuffer logic, one tree per agent."""

    def __init__(self, capacity: int, scores: dict, rng: np.random.Generator) -> None:
        tree_cap = 1
        while tree_cap < capacity:
            tree_cap *= 2
        self.size, self.scores = capacity, scores
        self.trees = [SumSegmentTree(tree_cap) for _ in range(N)]
        self.max_priority = [1.0] * N
        self.rng = rng

    def sample(self) -> list:
        out = []
        for tree in self.trees:
            total = tree.sum()
            idxes = [tree.find_prefixsum_idx(self.rng.random() * total) for _ in range(S)]
            probs = [tree[i] / total for i in idxes]
            weights = [(p * self.size) ** -BETA for p in probs]
            top = max(weights)
            out.append((idxes, [w / top for w in weights]))
        return out

    def update(self, idx: np.ndarray, td: np.ndarray) -> None:
        for a, tree in enumerate(self.trees):
            for i, d in zip(idx[a].tolist(), td[a].tolist(), strict=True):
                p = abs(d) + EPS
                tree[i] = p**ALPHA
                self.max_priority[a] = max(self.max_priority[a], p)

    def priorities(self, lam: float) -> np.ndarray:
        """float64[size, N]: the same numpy priority maths ours uses."""
        c_hat = normalise_difficulty(self.scores["difficulty"])
        cp = curiosity_priority(normalise_curiosity(self.scores["curiosity"]))
        return (kfold_priority(c_hat, lam) + ETA * cp + EPS) ** ALPHA

    def recompute(self, lam: float, leaves: int | None = None) -> None:
        """Write the priority column leaf by leaf (only the first `leaves` when timing a slice)."""
        w = self.priorities(lam)
        n = self.size if leaves is None else leaves
        for a, tree in enumerate(self.trees):
            for i, v in enumerate(w[:n, a].tolist()):
                tree[i] = v


# ----------------------------------------------------------------------------- ours
def build_ours(capacity: int, backend: str, scores: dict, algorithm: str) -> ReplayBuffer:
    """A full buffer (tiny obs/act so 1M rows stay small) with the given score columns."""
    samplers = [build_sampler(algorithm, SamplerArgs(capacity=capacity, alpha=ALPHA, backend=backend, eps=EPS, agent=a,
                                                     eta=ETA)) for a in range(N)]
    rb = ReplayBuffer(TransitionStorage(capacity=capacity, n_agents=N, obs_dim=1, act_dim=1), samplers)
    step = 100_000
    for start in range(0, capacity, step):
        t = min(step, capacity - start)
        z = np.zeros((t, N, 1), np.float32)
        rb.add(z, z, np.zeros((t, N), np.float32), z, np.zeros(t, np.float32), np.arange(start, start + t) // 30)
    slots = rb.valid_slots()
    gens = rb.generations(slots)
    rb.update_scores("difficulty", slots, gens, scores["difficulty"])
    rb.update_scores("curiosity", slots, gens, scores["curiosity"])
    return rb


def timed(fn, budget: float = 0.25, max_reps: int = 200) -> float:
    """Median-free mean seconds per call of fn() within a time budget (at least one call)."""
    reps, t0 = 0, time.perf_counter()
    while True:
        fn()
        reps += 1
        el = time.perf_counter() - t0
        if el >= budget or reps >= max_reps:
            return el / reps


def bench_capacity(capacity: int) -> dict:
    """Seconds per op {(who, op): s}; who in cdf, sumtree, ref."""
    rng = np.random.default_rng(0)
    scores = {"difficulty": rng.exponential(1.0, (capacity, N)).astype(np.float32),
              "curiosity": rng.exponential(0.1, (capacity, N)).astype(np.float32)}
    ours = {b: (build_ours(capacity, b, scores, "cmcl"), build_ours(capacity, b, scores, "per"))
            for b in ("cdf", "sumtree")}
    ref = Reference(capacity, scores, np.random.default_rng(1))
    ref.recompute(0.1, leaves=min(capacity, 20_000))
    for cm, _ in ours.values():
        cm.recompute_priorities(0.1)
    rngs = [np.random.default_rng(10 + a) for a in range(N)]
    idx = rng.integers(0, capacity, (N, S))
    td = rng.exponential(1.0, (N, S))
    ref_leaves = min(capacity, 20_000)
    res: dict = {}
    lam = [0.1]

    def next_lam() -> float:
        lam[0] = 0.1 + (lam[0] + 3e-6 - 0.1) % 0.9
        return lam[0]

    def per_update(per: ReplayBuffer) -> None:
        for a in range(N):
            per.update_priorities(a, idx[a], td[a])

    def per_step(per: ReplayBuffer) -> None:
        per_update(per)
        per.sample_all(S, rngs, BETA)

    def cmcl_step(cm: ReplayBuffer) -> None:
        cm.recompute_priorities(next_lam())
        cm.sample_all(S, rngs, BETA)

    for _ in range(ROUNDS):
        for b, (cm, per) in ours.items():
            for op, fn in (("sample", lambda cm=cm: cm.sample_all(S, rngs, BETA)),
                           ("update", lambda p=per: per_update(p)),
                           ("recompute", lambda cm=cm: cm.recompute_priorities(next_lam())),
                           ("per_step", lambda p=per: per_step(p)), ("cmcl_step", lambda cm=cm: cmcl_step(cm))):
                res.setdefault((b, op), []).append(timed(fn))
        res.setdefault(("ref", "sample"), []).append(timed(ref.sample, max_reps=50))
        res.setdefault(("ref", "update"), []).append(timed(lambda: ref.update(idx, td), max_reps=50))
        t_slice = timed(lambda: ref.recompute(next_lam(), leaves=ref_leaves), budget=0.1, max_reps=3)
        res.setdefault(("ref", "recompute"), []).append(t_slice * capacity / ref_leaves)
    out = {k: statistics.median(v) for k, v in res.items()}
    out[("ref", "per_step")] = out[("ref", "update")] + out[("ref", "sample")]
    out[("ref", "cmcl_step")] = out[("ref", "recompute")] + out[("ref", "sample")]
    out["extrapolated"] = ref_leaves < capacity
    return out


def main() -> None:
    t_start = time.perf_counter()
    results = {}
    ops = ("sample", "update", "recompute", "per_step", "cmcl_step")
    print(f"N={N} agents, batch {S}, alpha {ALPHA}, beta_IS {BETA}; ops/s (median of {ROUNDS} interleaved rounds)")
    print(f"{'capacity':>9} {'op':>10} {'ours cdf':>11} {'ours tree':>11} {'reference':>12} {'cdf/ref':>9} "
          f"{'tree/ref':>9}")
    for cap in CAPACITIES:
        r = results[cap] = bench_capacity(cap)
        for op in ops:
            mark = "~" if r["extrapolated"] and op in ("recompute", "cmcl_step") else " "
            print(f"{cap:>9} {op:>10} {1 / r[('cdf', op)]:>11.1f} {1 / r[('sumtree', op)]:>11.1f} "
                  f"{mark}{1 / r[('ref', op)]:>11.2f} {r[('ref', op)] / r[('cdf', op)]:>9.1f} "
                  f"{r[('ref', op)] / r[('sumtree', op)]:>9.1f}")
    base = CAPACITIES[0]
    print("cost growth vs capacity 5k (seconds per op relative to 5k; capacity grows 20x and 200x):")
    for op in ops:
        cells = []
        for who in ("cdf", "sumtree", "ref"):
            growth = [results[c][(who, op)] / results[base][(who, op)] for c in CAPACITIES[1:]]
            cells.append(f"{who} " + "/".join(f"{g:.1f}x" for g in growth))
        print(f"  {op:>10}: " + ", ".join(cells))
    print(f"total bench time {time.perf_counter() - t_start:.1f} s")
    r = results[100_000]
    print(f"ratio: {r[('ref', 'cmcl_step')] / r[('cdf', 'cmcl_step')]:.1f}")


if __name__ == "__main__":
    main()

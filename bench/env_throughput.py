"""World-steps per second of the sparse environments against their peers, in one process.

A world-step is all agents of one world acting once. Rows:
  * mpe2 simple_spread_v3 (N = 4, continuous actions): the single-env reference peer;
  * our PettingZoo sparse_spread_v0 (mpe2's World plus walls);
  * our batched numpy twin BatchedSparseSpread at B = 1, 64, 1024, 4096 (float32, auto-reset);
  * the predator-prey twin BatchedSparseTag at B = 1024;
  * VMAS simple_spread on CPU (torch) at the same B, when `vmas` is importable (skipped otherwise),
    with one torch thread like our single-threaded numpy: with two threads on a shared 2-core machine
    VMAS measured ~130 ms per step at B >= 64 (thread contention), far below its one-thread speed.
Random actions are drawn once into a pool and cycled, so every row times the environment only.
Episodes restart every 30 steps in the batched rows (25 or 30 in the PettingZoo rows, their default).
The last line is `ratio: X`, the twin at B = 1024 over mpe2.

    python bench/env_throughput.py [--seconds 1.5]
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable

import numpy as np

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

BATCHES = (1, 64, 1024, 4096)
POOL = 16


def timed(step: Callable[[int], int], seconds: float) -> float:
    """Call step(i) (returns world-steps done) until `seconds` have passed, after a warm-up; world-steps/s."""
    for i in range(3):
        step(i)
    done, i, start = 0, 0, time.perf_counter()
    while (elapsed := time.perf_counter() - start) < seconds:
        done += step(i)
        i += 1
    return done / elapsed


def pettingzoo_rate(make: Callable, seconds: float, sampler: Callable) -> float:
    """World-steps/s of one PettingZoo parallel env with pooled random actions."""
    env = make()
    env.reset(seed=0)
    names = list(env.possible_agents)
    pool = [{a: sampler(env, a) for a in names} for _ in range(POOL)]

    def step(i: int) -> int:
        if not env.agents:
            env.reset()
        env.step(pool[i % POOL])
        return 1

    return timed(step, seconds)


def twin_rate(cls, b: int, seconds: float) -> float:
    """World-steps/s of a batched twin with B worlds."""
    env = cls(b, seed=0, auto_reset=True)
    rng = np.random.default_rng(0)
    pool = rng.uniform(-1, 1, (POOL, b, env.num_agents, env.act_dim)).astype(np.float32)

    def step(i: int) -> int:
        env.step(pool[i % POOL])
        return b

    return timed(step, seconds)


def vmas_rate(b: int, seconds: float) -> float | None:
    """World-steps/s of VMAS simple_spread (4 agents, continuous) on CPU, or None if vmas is missing."""
    try:
        import torch
        import vmas
    except Exception:  # noqa: BLE001 - any import failure means: skip this peer
        return None
    torch.set_num_threads(1)  # 2 intra-op threads on this shared 2-core machine: ~130 ms/step (contention)
    env = vmas.make_env("simple_spread", num_envs=b, device="cpu", continuous_actions=True, n_agents=4, seed=0)
    gen = torch.Generator().manual_seed(0)
    pool = [[torch.rand(b, 2, generator=gen) * 2 - 1 for _ in range(4)] for _ in range(POOL)]
    env.reset()

    def step(i: int) -> int:
        if i % 30 == 29:
            env.reset()
        with torch.no_grad():
            env.step(pool[i % POOL])
        return b

    return timed(step, seconds)


def main() -> None:
    parser = argparse.ArgumentParser(description="environment throughput table")
    parser.add_argument("--seconds", type=float, default=1.5, help="time per measurement")
    args = parser.parse_args()
    from mpe2 import simple_spread_v3

    from cmcl.envs import sparse_spread_v0
    from cmcl.envs.batched import BatchedSparseSpread, BatchedSparseTag

    rows: list[tuple[str, int, float | None]] = []

    def add(name: str, b: int, rate: float | None) -> None:
        rows.append((name, b, rate))
        shown = "skipped (not importable)" if rate is None else f"{rate:14,.0f}"
        print(f"  measured {name:42s} B={b:<5d} {shown}", flush=True)

    mpe2_make = lambda: simple_spread_v3.parallel_env(N=4, continuous_actions=True)  # noqa: E731
    add("mpe2 simple_spread_v3 (PettingZoo)", 1, pettingzoo_rate(mpe2_make, args.seconds, _sample))
    add("cmcl sparse_spread_v0 (PettingZoo)", 1, pettingzoo_rate(sparse_spread_v0.parallel_env, args.seconds, _sample))
    for b in BATCHES:
        add("cmcl BatchedSparseSpread (numpy)", b, twin_rate(BatchedSparseSpread, b, args.seconds))
    add("cmcl BatchedSparseTag (numpy)", 1024, twin_rate(BatchedSparseTag, 1024, args.seconds))
    for b in BATCHES:
        add("VMAS simple_spread (torch CPU, 1 thread)", b, vmas_rate(b, args.seconds))
        if rows[-1][2] is None:
            break

    base = rows[0][2]
    print()
    print(f"{'environment':44s} {'B':>5s} {'world-steps/s':>15s} {'x mpe2':>9s}")
    for name, b, rate in rows:
        if rate is None:
            print(f"{name:44s} {b:5d} {'skipped':>15s} {'-':>9s}")
        else:
            print(f"{name:44s} {b:5d} {rate:15,.0f} {rate / base:9.1f}")
    twin = next(r for n, b, r in rows if n.startswith("cmcl BatchedSparseSpread") and b == 1024)
    vmas_1024 = next((r for n, b, r in rows if n.startswith("VMAS") and b == 1024 and r is not None), None)
    if vmas_1024:
        print(f"twin / VMAS at B=1024: {twin / vmas_1024:.1f}")
    print(f"ratio: {twin / base:.1f}")


def _sample(env, agent: str) -> np.ndarray:
    return env.action_space(agent).sample()


if __name__ == "__main__":
    main()

"""What agents of different sizes cost: zero padding plus action masks against the equal-size path, in one process.

Agents whose observation / action sizes differ (env.factory, e.g. mpe2 simple_speaker_listener_v4: obs 3 and 11,
actions 3 and 5) are padded to the largest sizes and their padded action entries masked (cmcl/envs/factory.py).
Rows, each timed in this process:
  * MADDPG update of N = 2 agents at obs 11 / act 5, no mask: the equal-size path (the peer);
  * the same update with the speaker-listener action mask [[1,1,1,0,0], [1,1,1,1,1]]: the cost of masking;
  * rollout side: VectorParallelEnv of B = 16 speaker-listener copies, steps per second (Python stepping of mpe2)
    against the bare mpe2 envs stepped in the same loop without the adapter: the cost of padding and bounds.
The padded width itself is a fixed cost of the layout: it is printed as the share of stored entries that are padding.
The last line is `ratio: X`, masked over unmasked update time.

    python bench/padding_cost.py [--seconds 2]
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cmcl.config import load_config  # noqa: E402
from cmcl.learners.maddpg import MADDPG  # noqa: E402
from cmcl.system import make_batched_env  # noqa: E402

OBS, ACT, N, S = (3, 11), (3, 5), 2, 128  # speaker-listener sizes, batch of S rows per owner
FACTORY = ["env.factory=mpe2.simple_speaker_listener_v4:parallel_env",
           "env.factory_kwargs={continuous_actions=true, max_cycles=25}", "env.num_envs=16",
           "teams.speaker.algorithm=maddpg", "teams.listener.algorithm=maddpg"]


def per_second(call: Callable[[], int], seconds: float) -> float:
    """Units per second of call() (which returns the units it did), after three warm-up calls."""
    for _ in range(3):
        call()
    done, start = 0, time.perf_counter()
    while (elapsed := time.perf_counter() - start) < seconds:
        done += call()
    return done / elapsed


def update_rate(mask: np.ndarray | None, seconds: float) -> float:
    """MADDPG updates per second on random per-owner batches of the padded widths."""
    od, ad = max(OBS), max(ACT)
    maddpg = MADDPG(N, od, ad, seed=0, act_mask=mask)
    rng = np.random.default_rng(0)
    batch = {"obs": rng.normal(size=(N, S, N, od)).astype(np.float32),
             "act": rng.uniform(-1, 1, (N, S, N, ad)).astype(np.float32),
             "rew": rng.normal(size=(N, S, N)).astype(np.float32),
             "next_obs": rng.normal(size=(N, S, N, od)).astype(np.float32), "done": np.zeros((N, S), np.float32)}

    def one() -> int:
        maddpg.update(batch)
        return 1

    return per_second(one, seconds)


def env_rates(seconds: float) -> tuple[float, float]:
    """(world-steps/s through VectorParallelEnv, world-steps/s of the same mpe2 envs stepped bare)."""
    config = load_config(None, FACTORY)
    env = make_batched_env(config, seed=0)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (8, env.num_envs, env.num_agents, env.act_dim)).astype(np.float32)
    count = [0]

    def adapted() -> int:
        env.step(actions[count[0] % 8])
        count[0] += 1
        return env.num_envs

    bare = env.envs  # the very same env objects, stepped directly once the adapter's row is timed
    pool = [{a: bare[0].action_space(a).sample() for a in bare[0].possible_agents} for _ in range(8)]

    def stepped() -> int:
        for e in bare:
            if not e.agents:
                e.reset()
            e.step(pool[count[0] % 8])
        count[0] += 1
        return len(bare)

    rate = per_second(adapted, seconds)
    for e in bare:
        e.reset(seed=0)
    return rate, per_second(stepped, seconds)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=2.0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    mask = np.zeros((N, max(ACT)), np.float32)
    for i, size in enumerate(ACT):
        mask[i, :size] = 1.0
    rounds = [(update_rate(None, args.seconds / 3), update_rate(mask, args.seconds / 3)) for _ in range(3)]
    equal, masked = max(r[0] for r in rounds), max(r[1] for r in rounds)  # alternated rounds, best of 3 each
    padding = 1 - (sum(OBS) + sum(ACT)) / (N * (max(OBS) + max(ACT)))
    adapted, bare = env_rates(args.seconds)
    print(f"MADDPG update, equal sizes (no mask):      {equal:8.1f} updates/s")
    print(f"MADDPG update, padded + action mask:       {masked:8.1f} updates/s")
    print(f"padding share of stored obs + act entries: {padding:8.2f}")
    print(f"mpe2 speaker-listener x16, bare:           {bare:8.0f} world-steps/s")
    print(f"mpe2 speaker-listener x16, adapter:        {adapted:8.0f} world-steps/s  "
          f"(adapter/bare {adapted / bare:.2f})")
    print(f"ratio: {equal / masked:.3f}")


if __name__ == "__main__":
    main()

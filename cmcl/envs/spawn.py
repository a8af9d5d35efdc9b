"""Initial states of the sparse MPE tasks (ALGORITHM.md §6): agents placed without overlap, landmarks and
obstacles uniform in their spawn squares.

Where it sits: imported by both implementations of each task, the PettingZoo reference (`sparse_spread_v0`,
`sparse_tag_v0`) and the batched numpy twins (`cmcl.envs.batched_spread`, `batched_tag`). Sampling lives in one
place so that a PettingZoo env and a twin with B = 1 that are reset with the same seed start from the same state.

Units: positions in arena units (the arena is the square [-0.5, 0.5]^2).
"""

from __future__ import annotations

import numpy as np

from cmcl.envs.common import ARENA_HALF
from cmcl.envs.params import SpreadParams, TagParams

MAX_SPAWN_TRIES = 10_000  # candidate draws per agent before giving up (sizes too large for the arena)
SPAWN_CANDIDATES = 2  # candidates drawn per world and round


def sample_agents(
    rng: np.random.Generator,
    n: int,
    radii: np.ndarray,
    fixed: np.ndarray | None = None,
    fixed_radius: float = 0.0,
) -> np.ndarray:
    """Place agents uniformly inside the walls without overlaps; returns float64[n, N, 2].

    Agent i is drawn in [-(0.5 - r_i), 0.5 - r_i]^2, rejecting draws that overlap an earlier agent
    (distance < r_i + r_j) or a fixed disc of `fixed` (float64[n, L, 2], radius `fixed_radius`).
    Each round draws SPAWN_CANDIDATES candidates per world and keeps the first valid one. Loops over
    agents and (rare) rounds, never over the n worlds.
    """
    num, k = len(radii), SPAWN_CANDIDATES
    pos = np.empty((num, 2, n))  # batch-last: numpy is fast on long inner loops
    fixed_t = None if fixed is None or fixed.shape[1] == 0 else fixed.transpose(1, 2, 0)  # [L, 2, n]
    for i in range(num):
        half = ARENA_HALF - radii[i]
        todo = np.arange(n)
        for _ in range(MAX_SPAWN_TRIES // k):
            cand = rng.uniform(-half, half, (2, k, len(todo)))  # [2, K, t]
            ok = np.ones((k, len(todo)), dtype=bool)
            for others, reach in ((pos[:i], radii[:i] + radii[i]), (fixed_t, fixed_radius + radii[i])):
                if others is None or len(others) == 0:
                    continue
                o = others[..., todo]  # [M, 2, t]
                d2 = np.square(cand[0][None] - o[:, 0, None]) + np.square(cand[1][None] - o[:, 1, None])  # [M, K, t]
                reach2 = np.square(np.broadcast_to(reach, (len(o),))).reshape(-1, 1, 1)
                ok &= (d2 >= reach2).all(axis=0)
            found = ok.any(axis=0)
            first = ok.argmax(axis=0)
            cols = np.flatnonzero(found)
            pos[i][:, todo[found]] = cand[:, first[found], cols]
            todo = todo[~found]
            if len(todo) == 0:
                break
        else:
            raise ValueError(f"could not place agent {i} without overlap in {MAX_SPAWN_TRIES} draws; sizes too large")
    return pos.transpose(2, 0, 1).copy()


def sample_spread(rng: np.random.Generator, n: int, p: SpreadParams) -> tuple[np.ndarray, np.ndarray]:
    """Initial state of n navigation worlds: (agent positions float64[n, N, 2], landmarks float64[n, L, 2])."""
    landmarks = rng.uniform(-p.landmark_spawn, p.landmark_spawn, (n, p.num_landmarks, 2))
    agents = sample_agents(rng, n, np.full(p.num_agents, p.agent_radius))
    return agents, landmarks


def sample_agent_tags(rng: np.random.Generator, n: int, p: SpreadParams) -> np.ndarray:
    """Navigation's per-episode agent tags (SpreadParams.agent_tags) of n worlds: float64[n, N], each U(0, 1).

    Drawn after `sample_spread`'s initial state from the same generator, by both implementations; without
    agent_tags nothing is drawn (the generator's stream is that of a world without tags)."""
    return rng.uniform(0.0, 1.0, (n, p.num_agents))


def sample_tag(rng: np.random.Generator, n: int, p: TagParams) -> tuple[np.ndarray, np.ndarray]:
    """Initial state of n predator-prey worlds: (agents float64[n, N, 2], obstacles float64[n, O, 2])."""
    obstacles = rng.uniform(-p.obstacle_spawn, p.obstacle_spawn, (n, p.num_obstacles, 2))
    agents = sample_agents(rng, n, p.radii, obstacles, p.obstacle_radius)
    return agents, obstacles

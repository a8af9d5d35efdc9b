"""Shared constants, argument checks and initial-state sampling for the sparse MPE tasks (ALGORITHM.md §6).

The tasks' world parameters are `cmcl.envs.params` (SpreadParams, TagParams).

Where it sits: imported by both implementations of each task, the PettingZoo reference
(`sparse_spread_v0`, `sparse_tag_v0`, built on mpe2's World) and the batched numpy twins
(`cmcl.envs.batched`). Sampling lives here so that a PettingZoo env and a twin with B = 1 that are
reset with the same seed start from the same state.

Units: positions in arena units (the arena is the square [-0.5, 0.5]^2), velocities per unit time,
time step dt = 0.1.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # the params module imports this one
    from cmcl.envs.params import SpreadParams, TagParams

# MPE physics, kept unchanged [V mpe2 _mpe_utils/core.py].
DT = 0.1
DAMPING = 0.25
CONTACT_FORCE = 100.0
CONTACT_MARGIN = 1e-3
MASS = 1.0
ARENA_HALF = 0.5  # walls at x = +-0.5 and y = +-0.5 (side 1)

MAX_SPAWN_TRIES = 10_000  # candidate draws per agent before giving up (sizes too large for the arena)
SPAWN_CANDIDATES = 2  # candidates drawn per world and round


def check_int(name: str, value: object, minimum: int) -> int:
    """Return `value` as int or raise ValueError naming the argument (bools and non-integers are refused)."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    if value < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value}")
    return int(value)


def check_float(name: str, value: object, low: float = 0.0, high: float = math.inf, low_open: bool = True) -> float:
    """Return `value` as a finite float in (low, high) (or [low, high) if not low_open) or raise ValueError."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise ValueError(f"{name} must be a number, got {value!r}")
    v = float(value)
    bad_low = v <= low if low_open else v < low
    if not math.isfinite(v) or bad_low or v >= high:
        lo = "(" if low_open else "["
        raise ValueError(f"{name} must be a finite number in {lo}{low}, {high}), got {value!r}")
    return v


def check_dtype(dtype: object) -> np.dtype:
    """The twins compute in float32 (default, fast) or float64 (parity with mpe2's float64 physics)."""
    dt = np.dtype(dtype)  # type: ignore[arg-type]
    if dt not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise ValueError(f"dtype must be float32 or float64, got {dtype!r}")
    return dt


def make_rng(seed: int | np.random.Generator | None) -> np.random.Generator:
    """A Generator from an int seed, a SeedSequence, an existing Generator (used as is) or None (fresh entropy)."""
    if isinstance(seed, np.random.Generator):
        return seed
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int | np.integer | np.random.SeedSequence)):
        raise ValueError(f"seed must be an int, a SeedSequence, a Generator or None, got {seed!r}")
    return np.random.default_rng(seed)


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


def sample_tag(rng: np.random.Generator, n: int, p: TagParams) -> tuple[np.ndarray, np.ndarray]:
    """Initial state of n predator-prey worlds: (agents float64[n, N, 2], obstacles float64[n, O, 2])."""
    obstacles = rng.uniform(-p.obstacle_spawn, p.obstacle_spawn, (n, p.num_obstacles, 2))
    agents = sample_agents(rng, n, p.radii, obstacles, p.obstacle_radius)
    return agents, obstacles


def check_state_arrays(state: dict[str, Any], shapes: dict[str, tuple[int, ...]],
                       accumulators: Iterable[str]) -> dict[str, np.ndarray]:
    """The world-state arrays of `state` (keys of `shapes`), each checked for presence, shape and finiteness.

    Keys other than those of `shapes` and the optional episode `accumulators` are refused (a state of the other
    task). Raises ValueError naming the key; nothing is loaded by this function.
    """
    arrays = {}
    for key, shape in shapes.items():
        if key not in state:
            raise ValueError(f"state is missing {key!r}")
        arr = np.asarray(state[key])
        if arr.shape != shape:
            raise ValueError(f"state[{key!r}] must have shape {shape}, got {arr.shape}")
        if not np.isfinite(arr).all():
            raise ValueError(f"state[{key!r}] must be finite")
        arrays[key] = arr
    unknown = set(state) - set(shapes) - set(accumulators)
    if unknown:
        raise ValueError(f"state has unknown keys {sorted(unknown)} (wrong task?)")
    return arrays

"""Shared constants, argument checks and initial-state sampling for the sparse MPE tasks (ALGORITHM.md §6).

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
from dataclasses import dataclass
from typing import Any

import numpy as np

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


@dataclass(frozen=True)
class SpreadParams:
    """Sparse cooperative navigation (ALGORITHM.md §6.1). Radii in arena units."""

    num_agents: int = 4
    agent_radius: float = 0.05
    landmark_radius: float = 0.05  # drawing only: landmarks are not collidable
    cover_radius: float = 0.1  # a landmark is covered by an agent whose centre is closer than this
    sensitivity: float = 5.0  # force = action * sensitivity
    landmark_spawn: float = 0.4  # landmarks uniform in [-0.4, 0.4]^2
    collision_reward: float = -1.0  # C1, at most once per agent per step (agent contact or wall hit)
    cover_reward: float = 4.0  # C2, at most once per agent per step
    shared_reward: bool = True  # every agent receives the team sum

    def validated(self) -> SpreadParams:
        """Raise ValueError naming the first invalid field; return self."""
        check_int("num_agents", self.num_agents, 1)
        check_float("agent_radius", self.agent_radius, 0.0, ARENA_HALF)
        check_float("landmark_radius", self.landmark_radius, 0.0, ARENA_HALF)
        check_float("cover_radius", self.cover_radius)
        check_float("sensitivity", self.sensitivity)
        check_float("landmark_spawn", self.landmark_spawn, 0.0, ARENA_HALF, low_open=False)
        check_float("collision_reward", self.collision_reward, -math.inf)
        check_float("cover_reward", self.cover_reward, -math.inf)
        return self

    @property
    def num_landmarks(self) -> int:
        return self.num_agents

    @property
    def obs_dim(self) -> int:
        """[vel(2), pos(2), landmark rel pos (2L), other agents' rel pos (2(N-1))]."""
        return 4 + 2 * self.num_landmarks + 2 * (self.num_agents - 1)


@dataclass(frozen=True)
class TagParams:
    """Sparse predator-prey (ALGORITHM.md §6.2). Predators are agents 0..m-1, prey m..m+n-1.

    Defaults are the calibrated world of §6.2 ("calibration" row; bench/tag_calibration.py): 2 predators
    and 2 prey at half MPE's absolute sizes, so that random policies on both sides give the predators
    ~0.45 of rounds (§6.2's first recommendation, 4 predators of radius 0.075 and prey of radius 0.05,
    gave 0.90). Radii and spawn ranges in arena units, speeds in arena units per unit time.
    """

    num_predators: int = 2  # calibrated [R]; §6.2's first recommendation was 4
    num_prey: int = 2
    num_obstacles: int = 3
    predator_radius: float = 0.0375  # calibrated [R]: MPE's 0.075 x 0.5
    prey_radius: float = 0.025  # calibrated [R]: MPE's 0.05 x 0.5; capture when distance < 0.0625
    obstacle_radius: float = 0.1
    predator_accel: float = 3.0  # force = action * accel
    predator_max_speed: float = 1.0
    prey_accel: float = 4.0
    prey_max_speed: float = 2.0  # twice the predators'
    obstacle_spawn: float = 0.3  # obstacle centres uniform in [-0.3, 0.3]^2
    capture_reward: float = 5.0  # D1, per (predator, prey) pair in contact: +5 to that predator, -5 to that prey
    wall_reward: float = -1.0  # D2: to any agent clamped at a wall this step
    shared_reward: bool = False  # D1 option: every predator receives +5 per pair in contact anywhere (MPE)

    def validated(self) -> TagParams:
        """Raise ValueError naming the first invalid field; return self."""
        check_int("num_predators", self.num_predators, 1)
        check_int("num_prey", self.num_prey, 1)
        check_int("num_obstacles", self.num_obstacles, 0)
        for name in ("predator_radius", "prey_radius"):
            check_float(name, getattr(self, name), 0.0, ARENA_HALF)
        check_float("obstacle_radius", self.obstacle_radius)
        for name in ("predator_accel", "predator_max_speed", "prey_accel", "prey_max_speed"):
            check_float(name, getattr(self, name))
        check_float("obstacle_spawn", self.obstacle_spawn, 0.0, ARENA_HALF, low_open=False)
        check_float("capture_reward", self.capture_reward, -math.inf)
        check_float("wall_reward", self.wall_reward, -math.inf)
        return self

    @property
    def num_agents(self) -> int:
        return self.num_predators + self.num_prey

    @property
    def obs_dims(self) -> tuple[int, ...]:
        """[vel, pos, obstacle rel pos (2O), other agents' rel pos (2(N-1)), other prey's velocities]."""
        base = 4 + 2 * self.num_obstacles + 2 * (self.num_agents - 1)
        return (base + 2 * self.num_prey,) * self.num_predators + (base + 2 * (self.num_prey - 1),) * self.num_prey

    @property
    def radii(self) -> np.ndarray:
        """float64[N] agent radii."""
        return np.array([self.predator_radius] * self.num_predators + [self.prey_radius] * self.num_prey)

    @property
    def accels(self) -> np.ndarray:
        """float64[N] action-to-force factors."""
        return np.array([self.predator_accel] * self.num_predators + [self.prey_accel] * self.num_prey)

    @property
    def max_speeds(self) -> np.ndarray:
        """float64[N] speed limits."""
        return np.array([self.predator_max_speed] * self.num_predators + [self.prey_max_speed] * self.num_prey)


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

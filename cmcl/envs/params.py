"""The world parameters of the two sparse MPE tasks: one frozen, self-validating dataclass per task.

Where it sits: the one home of every world parameter. The PettingZoo envs (`sparse_spread_v0.parallel_env(**fields)`
takes any field as a keyword), the batched twins (`BatchedSparseSpread(B, params)`), the run configuration
(`EnvConfig.spread` / `EnvConfig.tag`, whose TOML keys are these field names: cmcl.config.env) and the tests all
build or take these objects; none of them lists the fields again.

Units: lengths in arena units (the arena is the square [-0.5, 0.5]^2, side 1), speeds in arena units per unit
time (dt = 0.1), rewards per agent and step. Each `__post_init__` raises ValueError naming the field and the
value ("agent_radius must be ..., got 0.7"); the message starts with the field name.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cmcl.envs.common import ARENA_HALF, check_float, check_int

EPISODE_LENGTH = 30  # steps per episode of both tasks [P] (EnvConfig.episode_length, the twins, max_cycles)


def _check_rewards(params: SpreadParams | TagParams, names: tuple[str, ...]) -> None:
    """Check the reward fields `names` (any finite number, of either sign) and store `shared_reward` as a bool."""
    for name in names:
        check_float(name, getattr(params, name), -math.inf)
    object.__setattr__(params, "shared_reward", bool(params.shared_reward))


@dataclass(frozen=True)
class SpreadParams:
    """Sparse cooperative navigation (ALGORITHM.md §6.1): N agents, N landmarks, reward C1 + C2 per agent and step.

    Defaults are §6.1's [P] / [R] values, with the team reward of the PettingZoo env (`shared_reward=True`, MPE's
    `collaborative=True`); the run configuration's default is the individual reward (EnvConfig.spread).
    """

    num_agents: int = 4  # N agents, and as many landmarks [P]
    agent_radius: float = 0.05  # [R] MPE's default entity size; option 0.15 (simple_spread); in (0, 0.5)
    landmark_radius: float = 0.05  # drawing only: landmarks are not collidable; in (0, 0.5)
    # a landmark is covered by the closest agent whose centre is closer than this [P: 0.1]; smaller values make the
    # sparse reward rarer (the harder-task calibration of docs/RESULTS.md); > 0
    cover_radius: float = 0.1
    sensitivity: float = 5.0  # force = action x sensitivity (MPE's default [V]); > 0
    landmark_spawn: float = 0.4  # landmarks uniform in [-landmark_spawn, landmark_spawn]^2; in [0, 0.5)
    collision_reward: float = -1.0  # C1, at most once per agent per step (agent contact or wall hit) [P]
    cover_reward: float = 4.0  # C2, at most once per agent per step (covering a landmark) [P]
    shared_reward: bool = True  # True: every agent receives the team sum (MPE); False: its own C1 + C2 (§6.1 revised)

    def __post_init__(self) -> None:
        check_int("num_agents", self.num_agents, 1)
        check_float("agent_radius", self.agent_radius, 0.0, ARENA_HALF)
        check_float("landmark_radius", self.landmark_radius, 0.0, ARENA_HALF)
        check_float("cover_radius", self.cover_radius)
        check_float("sensitivity", self.sensitivity)
        check_float("landmark_spawn", self.landmark_spawn, 0.0, ARENA_HALF, low_open=False)
        _check_rewards(self, ("collision_reward", "cover_reward"))

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
    gave 0.90).
    """

    num_predators: int = 2  # m, calibrated [R]; §6.2's first recommendation was 4; >= 1
    num_prey: int = 2  # n; >= 1
    num_obstacles: int = 3  # immovable, collidable [P: 3 large obstacles]; >= 0
    predator_radius: float = 0.0375  # calibrated [R]: MPE's 0.075 x 0.5; in (0, 0.5)
    prey_radius: float = 0.025  # calibrated [R]: MPE's 0.05 x 0.5; capture when distance < 0.0625; in (0, 0.5)
    obstacle_radius: float = 0.1  # [R]; option 0.2 (MPE's "large"); > 0
    predator_accel: float = 3.0  # force = action x accel; > 0
    predator_max_speed: float = 1.0  # > 0
    prey_accel: float = 4.0  # > 0
    prey_max_speed: float = 2.0  # twice the predators' [P]; > 0
    obstacle_spawn: float = 0.3  # obstacle centres uniform in [-obstacle_spawn, obstacle_spawn]^2; in [0, 0.5)
    capture_reward: float = 5.0  # D1, per (predator, prey) pair in contact: +5 to that predator, -5 to that prey
    wall_reward: float = -1.0  # D2: to any agent clamped at a wall this step
    shared_reward: bool = False  # D1 option: every predator receives +5 per pair in contact anywhere (MPE)

    def __post_init__(self) -> None:
        check_int("num_predators", self.num_predators, 1)
        check_int("num_prey", self.num_prey, 1)
        check_int("num_obstacles", self.num_obstacles, 0)
        for name in ("predator_radius", "prey_radius"):
            check_float(name, getattr(self, name), 0.0, ARENA_HALF)
        for name in ("obstacle_radius", "predator_accel", "predator_max_speed", "prey_accel", "prey_max_speed"):
            check_float(name, getattr(self, name))
        check_float("obstacle_spawn", self.obstacle_spawn, 0.0, ARENA_HALF, low_open=False)
        _check_rewards(self, ("capture_reward", "wall_reward"))

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

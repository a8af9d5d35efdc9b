"""The world parameters of the two sparse MPE tasks: one frozen, self-validating dataclass per task.

Where it sits: the one home of every world parameter. The PettingZoo envs (`sparse_spread_v0.parallel_env(**fields)`
takes any field as a keyword), the batched twins (`BatchedSparseSpread(B, params)`), the run configuration
(`EnvConfig.spread` / `EnvConfig.tag`, whose TOML keys are these field names: cmcl.config.env) and the tests all
build or take these objects; none of them lists the fields again.

Units: lengths in arena units (the arena is the square [-0.5, 0.5]^2, side 1), speeds in arena units per unit
time (dt = 0.1), rewards per agent and step. Each field is declared with its meaning, unit and range rule
(cmcl.field_docs.documented; `python -m cmcl config env` prints them). Each `__post_init__` runs the rules and
raises ValueError naming the field and the value ("agent_radius must be ..., got 0.7"); the message starts with the
field name.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cmcl.envs.common import ARENA_HALF, FloatIn, IntAtLeast
from cmcl.field_docs import documented, ruled_fields

LENGTH, SPEED, REWARD = "arena units", "arena units per unit time", "per agent and step"
EPISODE_LENGTH = 30  # steps per episode of both tasks [P] (EnvConfig.episode_length, the twins, max_cycles)


def _check_fields(params: SpreadParams | TagParams) -> None:
    """Run every field's rule (its range, cmcl.field_docs) in field order; store `shared_reward` as a bool."""
    for name, value, rule in ruled_fields(params):
        rule.check(name, value)
    object.__setattr__(params, "shared_reward", bool(params.shared_reward))


@dataclass(frozen=True)
class SpreadParams:
    """Sparse cooperative navigation (ALGORITHM.md §6.1): N agents, N landmarks, reward C1 + C2 per agent and step.

    Defaults are §6.1's [P] / [R] values, with the team reward of the PettingZoo env (`shared_reward=True`, MPE's
    `collaborative=True`); the run configuration's default is the individual reward (EnvConfig.spread).
    """

    num_agents: int = documented(4, "N agents, and as many landmarks [P]", unit="agents", rule=IntAtLeast(1))
    agent_radius: float = documented(0.05, "an agent's radius [R]: MPE's default entity size; option 0.15 "
                                     "(simple_spread)", unit=LENGTH, rule=FloatIn(0.0, ARENA_HALF))
    landmark_radius: float = documented(0.05, "a landmark's radius, for drawing only: landmarks are not collidable",
                                        unit=LENGTH, rule=FloatIn(0.0, ARENA_HALF))
    cover_radius: float = documented(
        0.1, "a landmark is covered by the closest agent whose centre is closer than this [P: 0.1]; smaller values "
        "make the sparse reward rarer (the harder-task calibration of lab/RESULTS.md)", unit=LENGTH, rule=FloatIn())
    sensitivity: float = documented(5.0, "force = action × sensitivity (MPE's default [V])", unit="force per action "
                                    "unit", rule=FloatIn())
    landmark_spawn: float = documented(0.4, "landmarks are placed uniformly in [-landmark_spawn, landmark_spawn]^2",
                                       unit=LENGTH, rule=FloatIn(0.0, ARENA_HALF, low_open=False))
    collision_reward: float = documented(-1.0, "C1, at most once per agent per step (agent contact or wall hit) "
                                         "[P]", unit=REWARD, rule=FloatIn(-math.inf))
    cover_reward: float = documented(4.0, "C2, at most once per agent per step (covering a landmark) [P]",
                                     unit=REWARD, rule=FloatIn(-math.inf))
    shared_reward: bool = documented(True, "true: every agent receives the team sum (MPE); false: its own C1 + C2 "
                                     "(§6.1 revised)")
    agent_tags: bool = documented(False, "true: at every episode start each agent draws a tag u_i ~ U(0, 1) (per "
                                  "world, fixed for the episode) and agent i's observation ends with [u_i, u_j for "
                                  "j != i in index order] (N more columns), a tie-breaker for shared-parameter "
                                  "policies; false: no tags (MPE's observation)")

    def __post_init__(self) -> None:
        _check_fields(self)
        object.__setattr__(self, "agent_tags", bool(self.agent_tags))

    @property
    def num_landmarks(self) -> int:
        return self.num_agents

    @property
    def tags_at(self) -> int:
        """The flat column of an agent's own tag (agent_tags; the other agents' tags follow it): 4 + 2L + 2(N-1)."""
        return 4 + 2 * self.num_landmarks + 2 * (self.num_agents - 1)

    @property
    def obs_dim(self) -> int:
        """[vel(2), pos(2), landmark rel pos (2L), other agents' rel pos (2(N-1))], then with agent_tags the tags
        [own (1), other agents' in index order (N-1)]: 4 + 2L + 2(N-1) (+ N)."""
        return self.tags_at + (self.num_agents if self.agent_tags else 0)


@dataclass(frozen=True)
class TagParams:
    """Sparse predator-prey (ALGORITHM.md §6.2). Predators are agents 0..m-1, prey m..m+n-1.

    Defaults are the calibrated world of §6.2 ("calibration" row; lab/studies/tag_calibration.py): 2 predators
    and 2 prey at half MPE's absolute sizes, so that random policies on both sides give the predators
    ~0.45 of rounds (§6.2's first recommendation, 4 predators of radius 0.075 and prey of radius 0.05,
    gave 0.90).
    """

    num_predators: int = documented(2, "m predators, calibrated [R]; §6.2's first recommendation was 4",
                                    unit="agents", rule=IntAtLeast(1))
    num_prey: int = documented(2, "n prey", unit="agents", rule=IntAtLeast(1))
    num_obstacles: int = documented(3, "immovable, collidable obstacles [P: 3 large obstacles]", unit="obstacles",
                                    rule=IntAtLeast(0))
    predator_radius: float = documented(0.0375, "a predator's radius, calibrated [R]: MPE's 0.075 × 0.5",
                                        unit=LENGTH, rule=FloatIn(0.0, ARENA_HALF))
    prey_radius: float = documented(0.025, "a prey's radius, calibrated [R]: MPE's 0.05 × 0.5; capture when the "
                                    "distance < predator_radius + prey_radius (0.0625)", unit=LENGTH,
                                    rule=FloatIn(0.0, ARENA_HALF))
    obstacle_radius: float = documented(0.1, "an obstacle's radius [R]; option 0.2 (MPE's 'large')", unit=LENGTH,
                                        rule=FloatIn())
    predator_accel: float = documented(3.0, "a predator's force = action × accel", unit="force per action unit",
                                       rule=FloatIn())
    predator_max_speed: float = documented(1.0, "a predator's speed limit", unit=SPEED, rule=FloatIn())
    prey_accel: float = documented(4.0, "a prey's force = action × accel", unit="force per action unit",
                                   rule=FloatIn())
    prey_max_speed: float = documented(2.0, "a prey's speed limit: twice the predators' [P]", unit=SPEED,
                                       rule=FloatIn())
    obstacle_spawn: float = documented(0.3, "obstacle centres are placed uniformly in [-obstacle_spawn, "
                                       "obstacle_spawn]^2", unit=LENGTH, rule=FloatIn(0.0, ARENA_HALF, low_open=False))
    capture_reward: float = documented(5.0, "D1, per (predator, prey) pair in contact: +capture_reward to that "
                                       "predator, −capture_reward to that prey", unit=REWARD, rule=FloatIn(-math.inf))
    wall_reward: float = documented(-1.0, "D2: to any agent clamped at a wall this step", unit=REWARD,
                                    rule=FloatIn(-math.inf))
    shared_reward: bool = documented(False, "D1 option: every predator receives +capture_reward per pair in contact "
                                     "anywhere (MPE)")

    def __post_init__(self) -> None:
        _check_fields(self)

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

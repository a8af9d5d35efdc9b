"""Sparse predator-prey (ALGORITHM.md §6.2) as a PettingZoo ParallelEnv on mpe2's World.

Where it sits: the reference version of the pursuit task (evaluation, rendering, parity tests);
training rollouts use its batched twin `cmcl.envs.batched.BatchedSparseTag`.
The world's parameters and their defaults are `cmcl.envs.params.TagParams`: `parallel_env(max_cycles=30,
render_mode=None, **fields)` takes any of its fields as a keyword; the numbers below are the defaults.

m predators ("predator_0".., default m = 2, radius 0.0375, accel 3, max speed 1) and n prey ("prey_0"..,
default n = 2, radius 0.025, accel 4, max speed 2) among O immovable, collidable obstacles (default 3,
radius 0.1, centres uniform in [-0.3, 0.3]^2) in the walled square [-0.5, 0.5]^2. Agents are ordered
predators first, then prey. The defaults are §6.2's calibrated world: random policies on both sides give
the predators ~0.45 of rounds (lab/studies/tag_calibration.py); radii in arena units, speeds per unit time.
Rewards per step:
  D1: for every (predator, prey) pair in contact (distance < r_pred + r_prey): +5 to that predator
      and -5 to that prey; prey are not removed. With shared_reward=True every predator receives +5
      per pair in contact (MPE simple_tag's team reward);
  D2: -1 to any agent clamped at a wall this step.
Observation of agent i (MPE layout; predators 4 + 2O + 2(N-1) + 2n, prey 2 less):
  [vel(2), pos(2), obstacle_o - pos_i (2O), pos_j - pos_i for j != i ascending (2(N-1)),
   vel_j for prey j != i ascending].
Step infos per agent: wall_hit, captures (contact pairs involving this agent); at the last step also
"episode": captures (pair-steps in contact), predator_win (captures >= 1), wall_hits (agent-steps),
return (float64[N] returns).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from mpe2._mpe_utils.core import Agent, Landmark

from cmcl.envs import metrics
from cmcl.envs.params import EPISODE_LENGTH, TagParams
from cmcl.envs.pz_base import SparseParallelEnv
from cmcl.envs.spawn import sample_tag

NAME = "sparse_tag_v0"


class SparseTagEnv(SparseParallelEnv):
    """The predator-prey task; construct through `parallel_env(...)`."""

    metadata = {**SparseParallelEnv.metadata, "name": NAME}

    def __init__(self, params: TagParams, max_cycles: int = EPISODE_LENGTH, render_mode: str | None = None) -> None:
        self.params = params
        self.obs_dims = params.obs_dims
        super().__init__(max_cycles, render_mode)

    def _build_world(self) -> None:
        p = self.params
        self.world.agents = [Agent() for _ in range(p.num_agents)]
        for i, agent in enumerate(self.world.agents):
            predator = i < p.num_predators
            agent.name = f"predator_{i}" if predator else f"prey_{i - p.num_predators}"
            agent.size = p.predator_radius if predator else p.prey_radius
            agent.accel = p.predator_accel if predator else p.prey_accel
            agent.max_speed = p.predator_max_speed if predator else p.prey_max_speed
            agent.color = np.array([0.85, 0.35, 0.35]) if predator else np.array([0.35, 0.85, 0.35])
        self.world.landmarks = [Landmark() for _ in range(p.num_obstacles)]
        for l, lm in enumerate(self.world.landmarks):
            lm.name = f"obstacle_{l}"
            lm.collide = True
            lm.size = p.obstacle_radius
            lm.color = np.array([0.25, 0.25, 0.25])

    def _sample(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        agents, obstacles = sample_tag(rng, 1, self.params)
        return agents[0], obstacles[0]

    def _zero_stats(self) -> None:
        self.stats: dict[str, Any] = {
            "ep_return": np.zeros(self.params.num_agents),
            "ep_wall_hits": 0,
            "ep_captures": 0,
            "ep_steps": 0,
        }

    def _observe_agent(self, i: int) -> np.ndarray:
        """float64[obs_dims[i]] for agent i, mpe2's simple_tag layout."""
        me = self.world.agents[i]
        prey = self.world.agents[self.params.num_predators :]
        parts = [me.state.p_vel, me.state.p_pos]
        parts += [lm.state.p_pos - me.state.p_pos for lm in self.world.landmarks]
        parts += [o.state.p_pos - me.state.p_pos for o in self.world.agents if o is not me]
        parts += [o.state.p_vel for o in prey if o is not me]
        return np.concatenate(parts)

    def _score(self, wall_hit: np.ndarray) -> tuple[np.ndarray, list[dict[str, Any]]]:
        p, agents = self.params, self.world.agents
        m = p.num_predators
        rewards = np.where(wall_hit, p.wall_reward, 0.0)
        involved = np.zeros(len(agents), dtype=np.int64)
        captures = 0
        for q in range(m, len(agents)):
            for k in range(m):
                d = np.sqrt(np.sum(np.square(agents[k].state.p_pos - agents[q].state.p_pos)))
                if d < agents[k].size + agents[q].size:
                    captures += 1
                    involved[k] += 1
                    involved[q] += 1
                    rewards[q] -= p.capture_reward
                    if not p.shared_reward:
                        rewards[k] += p.capture_reward
        if p.shared_reward:
            rewards[:m] += p.capture_reward * captures
        s = self.stats
        s["ep_return"] = s["ep_return"] + rewards
        s["ep_wall_hits"] += int(wall_hit.sum())
        s["ep_captures"] += captures
        s["ep_steps"] += 1
        infos = [{"wall_hit": bool(wall_hit[i]), "captures": int(involved[i])} for i in range(len(agents))]
        return rewards, infos

    def _summary(self) -> dict[str, Any]:
        s = self.stats
        return {
            "captures": int(s["ep_captures"]),
            "predator_win": bool(metrics.predator_win(np.array([s["ep_captures"]]))[0]),
            "wall_hits": int(s["ep_wall_hits"]),
            "return": s["ep_return"].copy(),
        }


def parallel_env(max_cycles: int = EPISODE_LENGTH, render_mode: str | None = None, **fields: Any) -> SparseTagEnv:
    """The sparse predator-prey task as a PettingZoo ParallelEnv (predators first, then prey).

    fields: any of `TagParams`'s (num_predators, num_prey, num_obstacles, predator_radius, shared_reward, ...), as
    keywords; an unknown one raises TypeError, an out-of-range one ValueError naming it.
    """
    return SparseTagEnv(TagParams(**fields), max_cycles=max_cycles, render_mode=render_mode)

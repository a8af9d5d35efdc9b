"""Sparse cooperative navigation (ALGORITHM.md §6.1) as a PettingZoo ParallelEnv on mpe2's World.

Where it sits: the reference version of the navigation task (evaluation, rendering, parity tests);
training rollouts use its batched twin `cmcl.envs.batched.BatchedSparseSpread`.
The world's parameters and their defaults are `cmcl.envs.params.SpreadParams`: `parallel_env(max_cycles=30,
render_mode=None, **fields)` takes any of its fields as a keyword; the numbers below are the defaults.

N agents (radius 0.05) and N landmarks (not collidable) in the walled square [-0.5, 0.5]^2.
Per-agent, per-step reward C1 + C2:
  C1 = -1 if the agent touches another agent (distance < r_v + r_u, never itself) or hit a wall this step;
  C2 = +4 if the agent is within 0.1 of a landmark and is the closest agent to it (ties: lowest index).
With shared_reward=True (default) every agent receives the team sum.
Observation of agent i (obs_dim = 4N + 2, 18 for N = 4):
  [vel(2), pos(2), landmark_l - pos_i for l = 0..N-1 (2N), pos_j - pos_i for j != i ascending (2(N-1))];
  with agent_tags=True then [u_i, u_j for j != i ascending] (N more: obs_dim = 5N + 2), the agents' tags u ~ U(0, 1)
  drawn at every reset and fixed through the episode (`tags`; in the world state as "tags", cmcl.envs.state).
Action: float[2] in [-1, 1] (clipped), force = action * 5.0.
Step infos per agent: wall_hit, collided, covering, reward_unshared; at the last step also "episode":
coverage (final step), success (final step), coverage_mean (per-step average), collisions (agent pairs
in contact, summed over steps), wall_hits (agent-steps clamped), return (float64[N] unshared returns).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from mpe2._mpe_utils.core import Agent, Landmark

from cmcl.envs import metrics
from cmcl.envs.params import EPISODE_LENGTH, SpreadParams
from cmcl.envs.pz_base import SparseParallelEnv, agent_contacts
from cmcl.envs.spawn import sample_agent_tags, sample_spread

NAME = "sparse_spread_v0"


class SparseSpreadEnv(SparseParallelEnv):
    """The navigation task; construct through `parallel_env(...)`."""

    metadata = {**SparseParallelEnv.metadata, "name": NAME}

    def __init__(self, params: SpreadParams, max_cycles: int = EPISODE_LENGTH, render_mode: str | None = None) -> None:
        self.params = params
        self.obs_dims = (params.obs_dim,) * params.num_agents
        # params.agent_tags: float64[N], drawn at every reset after the initial state (None without tags)
        self.tags = np.zeros(params.num_agents) if params.agent_tags else None
        super().__init__(max_cycles, render_mode)

    def _build_world(self) -> None:
        p = self.params
        self.world.agents = [Agent() for _ in range(p.num_agents)]
        for i, agent in enumerate(self.world.agents):
            agent.name = f"agent_{i}"
            agent.size = p.agent_radius
            agent.accel = p.sensitivity
            agent.max_speed = None
            agent.color = np.array([0.35, 0.35, 0.85])
        self.world.landmarks = [Landmark() for _ in range(p.num_landmarks)]
        for l, lm in enumerate(self.world.landmarks):
            lm.name = f"landmark_{l}"
            lm.collide = False
            lm.size = p.landmark_radius
            lm.color = np.array([0.25, 0.25, 0.25])

    def _sample(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        agents, landmarks = sample_spread(rng, 1, self.params)
        if self.tags is not None:  # the episode's tags, drawn as the twin draws them (spawn.sample_agent_tags)
            self.tags[:] = sample_agent_tags(rng, 1, self.params)[0]
        return agents[0], landmarks[0]

    def episode_constants(self) -> dict[str, np.ndarray]:
        return {} if self.tags is None else {"tags": self.tags}

    def _render_rings(self) -> tuple[float, ...]:
        return (self.params.cover_radius,)

    def _zero_stats(self) -> None:
        n = self.params.num_agents
        self.stats: dict[str, Any] = {
            "ep_return": np.zeros(n),
            "ep_wall_hits": 0,
            "ep_collisions": 0,
            "ep_coverage_sum": 0.0,
            "ep_steps": 0,
        }

    def _observe_agent(self, i: int) -> np.ndarray:
        """float64[obs_dim] for agent i, mpe2's simple_spread layout without communication."""
        me = self.world.agents[i]
        parts = [me.state.p_vel, me.state.p_pos]
        parts += [lm.state.p_pos - me.state.p_pos for lm in self.world.landmarks]
        parts += [o.state.p_pos - me.state.p_pos for o in self.world.agents if o is not me]
        if self.tags is not None:
            parts += [self.tags[i : i + 1], np.delete(self.tags, i)]
        return np.concatenate(parts)

    def _score(self, wall_hit: np.ndarray) -> tuple[np.ndarray, list[dict[str, Any]]]:
        p, agents = self.params, self.world.agents
        n = len(agents)
        collided, pairs = agent_contacts(agents)
        covering = np.zeros(n, dtype=bool)
        covered = 0
        for lm in self.world.landmarks:
            d = [np.sqrt(np.sum(np.square(a.state.p_pos - lm.state.p_pos))) for a in agents]
            closest = int(np.argmin(d))
            if d[closest] < p.cover_radius:
                covering[closest] = True
                covered += 1
        unshared = np.where(collided | wall_hit, p.collision_reward, 0.0) + np.where(covering, p.cover_reward, 0.0)
        rewards = np.full(n, unshared.sum()) if p.shared_reward else unshared
        s = self.stats
        s["ep_return"] = s["ep_return"] + unshared
        s["ep_wall_hits"] += int(wall_hit.sum())
        s["ep_collisions"] += pairs
        s["ep_coverage_sum"] += covered / len(self.world.landmarks)
        s["ep_steps"] += 1
        infos = [
            {
                "wall_hit": bool(wall_hit[i]),
                "collided": bool(collided[i]),
                "covering": bool(covering[i]),
                "reward_unshared": float(unshared[i]),
            }
            for i in range(n)
        ]
        return rewards, infos

    def _summary(self) -> dict[str, Any]:
        pos = np.array([a.state.p_pos for a in self.world.agents])[None]  # [1, N, 2]
        lms = np.array([lm.state.p_pos for lm in self.world.landmarks])[None]  # [1, L, 2]
        cover = metrics.cover_matrix(pos, lms, self.params.cover_radius)
        s = self.stats
        return {
            "coverage": float(metrics.coverage_rate(cover)[0]),
            "success": bool(metrics.success(cover)[0]),
            "coverage_mean": s["ep_coverage_sum"] / max(s["ep_steps"], 1),
            "collisions": int(s["ep_collisions"]),
            "wall_hits": int(s["ep_wall_hits"]),
            "return": s["ep_return"].copy(),
        }


def parallel_env(max_cycles: int = EPISODE_LENGTH, render_mode: str | None = None, **fields: Any) -> SparseSpreadEnv:
    """The sparse navigation task as a PettingZoo ParallelEnv; agents "agent_0".."agent_{N-1}".

    fields: any of `SpreadParams`'s (num_agents, agent_radius, cover_radius, shared_reward, ...), as keywords;
    an unknown one raises TypeError, an out-of-range one ValueError naming it.
    """
    return SparseSpreadEnv(SpreadParams(**fields), max_cycles=max_cycles, render_mode=render_mode)

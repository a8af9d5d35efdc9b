"""PettingZoo ParallelEnv base for the sparse tasks, on mpe2's World physics plus walls.

Where it sits: the reference implementation and the renderer of `sparse_spread_v0` and
`sparse_tag_v0` (subclasses fill in world building, rewards and observations). The batched twins in
`cmcl.envs.batched` must match it (tests/test_env_parity.py). Per step:

1. actions: dict agent -> float[2]; clipped to [-1, 1]; force = action * sensitivity (accel);
2. mpe2 `World.step()` (contact forces, integration in mpe2's order, max-speed clamp), with one guard:
   coincident discs (possible when two agents are clamped into the same corner) exert no force
   instead of NaN (`WalledWorld`);
3. walls: for each agent and axis, if |x| > 0.5 - r: x = +-(0.5 - r), that velocity component = 0,
   and the agent's wall-hit flag is set;
4. rewards and observations from the post-wall state.

Episodes always last `max_cycles` steps: `terminations` are always False and `truncations` become
True at the last step (a time limit: learners bootstrap there, ALGORITHM.md §7 property 33).
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from mpe2._mpe_utils.core import World
from pettingzoo import ParallelEnv

from cmcl.envs.common import ARENA_HALF, CONTACT_FORCE, CONTACT_MARGIN, DAMPING, DT, check_int, make_rng
from cmcl.envs.render import draw_world


def agent_contacts(agents: list) -> tuple[np.ndarray, int]:
    """(bool[N] agents touching another agent, the number of agent pairs in contact): distance < r_v + r_u."""
    n = len(agents)
    collided = np.zeros(n, dtype=bool)
    pairs = 0
    for v in range(n):
        for u in range(v + 1, n):
            d = np.sqrt(np.sum(np.square(agents[v].state.p_pos - agents[u].state.p_pos)))
            if d < agents[v].size + agents[u].size:
                collided[v] = collided[u] = True
                pairs += 1
    return collided, pairs


class WalledWorld(World):
    """mpe2's World, unchanged except that two discs at exactly the same point exert no contact force.

    mpe2 divides by the centre distance, so coincident discs produce NaN forever. With walls this
    happens: two agents of equal radius pushed into the same corner are clamped to the same point.
    The direction of the force is undefined there; mpe2's formula gives 0 * inf, we give 0.
    """

    def get_collision_force(self, entity_a, entity_b):
        if entity_a.collide and entity_b.collide and np.array_equal(entity_a.state.p_pos, entity_b.state.p_pos):
            return [None, None]
        return super().get_collision_force(entity_a, entity_b)


class SparseParallelEnv(ParallelEnv):
    """Common machinery; subclasses define `_build_world`, `_sample`, `_observe_agent`, `_score`, `_summary`."""

    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 10, "is_parallelizable": True}

    def __init__(self, max_cycles: int, render_mode: str | None) -> None:
        self.max_cycles = check_int("max_cycles", max_cycles, 1)
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self.world = WalledWorld()
        self.world.dim_c = 0
        self.world.dt, self.world.damping = DT, DAMPING
        self.world.contact_force, self.world.contact_margin = CONTACT_FORCE, CONTACT_MARGIN
        self._build_world()
        for agent in self.world.agents:
            agent.silent = True
            agent.collide = True
            agent.state.p_pos = np.zeros(2)
            agent.state.p_vel = np.zeros(2)
            agent.action.u = np.zeros(2)
        for lm in self.world.landmarks:
            lm.movable = False
            lm.state.p_pos = np.zeros(2)
            lm.state.p_vel = np.zeros(2)
        self.possible_agents = [a.name for a in self.world.agents]
        self.agents: list[str] = []
        self._index = {name: i for i, name in enumerate(self.possible_agents)}
        self._accel = np.array([a.accel for a in self.world.agents], dtype=np.float64)  # [N]
        self._wall_limit = np.array([ARENA_HALF - a.size for a in self.world.agents])  # [N]
        self._action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
        self._obs_spaces = {
            name: spaces.Box(-np.inf, np.inf, (dim,), np.float32)
            for name, dim in zip(self.possible_agents, self.obs_dims, strict=True)
        }
        self.state_space = spaces.Box(-np.inf, np.inf, (sum(self.obs_dims),), np.float32)
        self._rng = make_rng(None)
        self.steps = 0
        self._zero_stats()

    # ----- subclass hooks -------------------------------------------------------------------
    obs_dims: tuple[int, ...] = ()

    def _build_world(self) -> None:
        raise NotImplementedError

    def _sample(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """(agent positions float64[N, 2], landmark positions float64[L, 2]) for a new episode."""
        raise NotImplementedError

    def _observe_agent(self, i: int) -> np.ndarray:
        raise NotImplementedError

    def _score(self, wall_hit: np.ndarray) -> tuple[np.ndarray, list[dict[str, Any]]]:
        """(rewards float64[N] as handed out, per-agent step infos); also updates the episode stats."""
        raise NotImplementedError

    def _summary(self) -> dict[str, Any]:
        """Per-episode statistics, read at the final step."""
        raise NotImplementedError

    def _zero_stats(self) -> None:
        raise NotImplementedError

    def episode_constants(self) -> dict[str, np.ndarray]:
        """Per-episode constants beyond the physical state, as their live float64 arrays (navigation's agent tags
        "tags" float64[N]); in the world state of cmcl.envs.state. None by default."""
        return {}

    # ----- PettingZoo API ---------------------------------------------------------------------
    def observation_space(self, agent: str) -> spaces.Space:
        """Box(-inf, inf, (obs_dim,), float32); the same object on every call."""
        return self._obs_spaces[agent]

    def action_space(self, agent: str) -> spaces.Space:
        """Box(-1, 1, (2,), float32): a force direction; values outside [-1, 1] are clipped."""
        return self._action_space

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """Start an episode: obs dict agent -> float32[obs_dim], infos dict agent -> {}."""
        if seed is not None:
            self._rng = make_rng(seed)
        agents, landmarks = self._sample(self._rng)
        self.place(agents, np.zeros_like(agents), landmarks, step=0)
        return self.observe_all(), {name: {} for name in self.agents}

    def place(self, agents: np.ndarray, velocities: np.ndarray, landmarks: np.ndarray, step: int) -> None:
        """Set the world state (float64[N, 2], float64[N, 2], float64[L, 2]) and the step counter."""
        for i, agent in enumerate(self.world.agents):
            agent.state.p_pos = np.array(agents[i], dtype=np.float64)
            agent.state.p_vel = np.array(velocities[i], dtype=np.float64)
        for l, lm in enumerate(self.world.landmarks):
            lm.state.p_pos = np.array(landmarks[l], dtype=np.float64)
        self.steps = int(step)
        self.agents = self.possible_agents[:]
        self._zero_stats()

    def observe_all(self) -> dict[str, np.ndarray]:
        """Observations of the live agents, float32[obs_dim] each."""
        return {name: self._observe_agent(self._index[name]).astype(np.float32) for name in self.agents}

    def _parse_actions(self, actions: dict) -> np.ndarray:
        """float64[N, 2] clipped actions; ValueError on missing/unknown agents, wrong shape, NaN/inf."""
        if not isinstance(actions, dict):
            raise ValueError(f"actions must be a dict agent -> float[2], got {type(actions).__name__}")
        unknown = set(actions) - set(self.possible_agents)
        if unknown:
            raise ValueError(f"actions has unknown agents {sorted(map(str, unknown))}")
        out = np.zeros((len(self.possible_agents), 2))
        for name in self.agents:
            if name not in actions:
                raise ValueError(f"actions is missing agent {name!r}")
            a = np.asarray(actions[name], dtype=np.float64)
            if a.shape != (2,):
                raise ValueError(f"action of {name} must have shape (2,), got {a.shape}")
            if not np.isfinite(a).all():
                raise ValueError(f"action of {name} must be finite, got {a.tolist()}")
            out[self._index[name]] = np.clip(a, -1.0, 1.0)
        return out

    def _apply_walls(self) -> np.ndarray:
        """Clamp agents inside the walls; zero the clamped velocity component. Returns bool[N] wall hits."""
        hits = np.zeros(len(self.world.agents), dtype=bool)
        for i, agent in enumerate(self.world.agents):
            lim = self._wall_limit[i]
            for c in range(2):
                x = agent.state.p_pos[c]
                if x > lim or x < -lim:
                    agent.state.p_pos[c] = lim if x > 0 else -lim
                    agent.state.p_vel[c] = 0.0
                    hits[i] = True
        return hits

    def step(self, actions: dict) -> tuple[dict, dict, dict, dict, dict]:
        """One world step for all agents. Returns obs, rewards, terminations, truncations, infos.

        At the last step every agent's info also holds "episode": the per-episode statistics.
        """
        if not self.agents:
            raise RuntimeError("step() called with no live agents: the episode has ended, call reset()")
        u = self._parse_actions(actions)
        for i, agent in enumerate(self.world.agents):
            agent.action.u = u[i] * self._accel[i]
        self.world.step()
        wall_hit = self._apply_walls()
        rewards, step_infos = self._score(wall_hit)
        self.steps += 1
        obs = self.observe_all()
        done = self.steps >= self.max_cycles
        infos = {name: step_infos[self._index[name]] for name in self.agents}
        if done:
            summary = self._summary()
            for name in self.agents:
                infos[name]["episode"] = dict(summary)
        rew = {name: float(rewards[self._index[name]]) for name in self.agents}
        terms = {name: False for name in self.agents}
        truncs = {name: done for name in self.agents}
        if done:
            self.agents = []
        return obs, rew, terms, truncs, infos

    def render(self) -> np.ndarray | None:
        """uint8[H, W, 3] frame with walls when render_mode == "rgb_array"; None (with a warning) otherwise."""
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; pass render_mode='rgb_array'")
            return None
        return draw_world(self.world, rings=self._render_rings())

    def _render_rings(self) -> tuple[float, ...]:
        return ()

    def close(self) -> None:
        """Nothing to release: frames are drawn on a fresh offscreen surface each time."""

    def state(self) -> np.ndarray:
        """float32[sum(obs_dims)]: all agents' observations concatenated (mpe2's convention)."""
        return np.concatenate([self._observe_agent(i).astype(np.float32) for i in range(len(self.world.agents))])

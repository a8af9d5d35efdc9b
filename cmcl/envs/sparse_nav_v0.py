"""All-or-nothing (VACL) and gated (SPMARL) sparse navigation as a PettingZoo ParallelEnv on mpe2's World.

The rules, their sources (jiayu-ch15/Variational-Automatic-Curriculum-Learning envs/mpe/scenarios/simple_spread.py;
wenshuaizhao/spmarl envs/mpe/scenarios/simple_spread.py) and where this differs from them: `cmcl.envs.sparse_nav`,
which also holds the world parameters (NavParams, VARIANTS) and the batched twin (BatchedSparseNav) this env is
checked against (tests/test_sparse_nav.py).

Train it through `env.factory` (the presets configs/vacl_n4_maddpg.toml, vacl_n8_maddpg.toml, spmarl_n8_maddpg.toml):

    [env]
    factory = "cmcl.envs.sparse_nav_v0:parallel_env"
    factory_kwargs = {variant = "vacl", num_agents = 4}
    episode_length = 70
    success_key = "success"
    coverage_key = "coverage"

Per step, every agent's info: success (every landmark covered now), coverage (the covered fraction now), covered
(landmarks covered), collided, reward_team; the runners read success / coverage at the episode's last step, which
is the held-out success of the sources. At the last step also "episode" (as the twin's info["episode"]).
Observation, action and physics as the twin: obs float32[obs_dim], action Box(-1, 1, (2,)) (force = action x 5),
mpe2's World without walls; episodes last `episode_length` steps (truncations, never terminations).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from cmcl.envs import sparse_nav
from cmcl.envs.pz_base import SparseParallelEnv, agent_contacts
from cmcl.envs.render import draw_world
from cmcl.envs.sparse_nav import NavParams, nav_settings, sample_nav
from cmcl.envs.sparse_spread_v0 import SparseSpreadEnv

NAME = "sparse_nav_v0"


class SparseNavEnv(SparseSpreadEnv):
    """The navigation variants of cmcl.envs.sparse_nav; construct through `parallel_env(...)`. Its world is built as
    sparse_spread_v0's (agents, landmarks; `_build_world`); sampling, observations, rewards and walls are its own."""

    metadata = {**SparseParallelEnv.metadata, "name": NAME}

    def __init__(self, params: NavParams, render_mode: str | None = None) -> None:
        self.params = params  # type: ignore[assignment]  (NavParams has the fields _build_world reads)
        self.variant_params = params  # the world the settings (set_setting) are applied to
        self.settings: dict[str, float] = {}  # world settings the next reset takes (cmcl.envs.world_settings)
        self.obs_dims = (params.obs_dim,) * params.num_agents
        self.tags = None
        SparseParallelEnv.__init__(self, params.episode_length, render_mode)

    def set_setting(self, name: str, value: float) -> None:
        """World setting `name` (spawn_scale, cover_radius, gate; cmcl.envs.world_settings) = `value` from the next
        reset on."""
        nav_settings(self.variant_params, name, value)  # refuses an unknown name
        self.settings[name] = float(value)

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """Start an episode at the world settings given so far (`set_setting`, or options={"settings": {name:
        value}})."""
        for name, value in ((options or {}).get("settings") or {}).items():
            self.set_setting(name, value)
        fields: dict[str, Any] = {}
        for name, value in self.settings.items():
            fields.update(nav_settings(self.variant_params, name, value))
        self.params = replace(self.variant_params, **fields)  # type: ignore[assignment]
        return super().reset(seed, options)

    def _sample(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        agents, landmarks = sample_nav(rng, 1, self.params)
        return agents[0], landmarks[0]

    def _apply_walls(self) -> np.ndarray:
        """The open plane: nothing is clamped."""
        return np.zeros(len(self.world.agents), dtype=bool)

    def _zero_stats(self) -> None:
        self.stats: dict[str, Any] = {"ep_return": np.zeros(self.params.num_agents), "ep_collisions": 0,
                                      "ep_coverage_sum": 0.0, "ep_steps": 0}

    def covered(self) -> np.ndarray:
        """bool[L]: landmark l has some agent's centre closer than cover_radius."""
        pos = np.array([a.state.p_pos for a in self.world.agents])
        lms = np.array([lm.state.p_pos for lm in self.world.landmarks])
        d = np.sqrt(np.square(lms[None] - pos[:, None]).sum(-1))  # [N, L]
        return d.min(axis=0) < self.params.cover_radius

    def _observe_agent(self, i: int) -> np.ndarray:
        me = self.world.agents[i]
        bits = self.covered()
        parts = [me.state.p_vel, me.state.p_pos]
        for l, lm in enumerate(self.world.landmarks):
            if self.params.cover_bits:
                parts.append(np.array([float(bits[l])]))
            parts.append(lm.state.p_pos - me.state.p_pos)
        parts += [o.state.p_pos - me.state.p_pos for o in self.world.agents if o is not me]
        return np.concatenate(parts)

    def _score(self, wall_hit: np.ndarray) -> tuple[np.ndarray, list[dict[str, Any]]]:
        p, agents = self.params, self.world.agents
        n = len(agents)
        collided, pairs = agent_contacts(agents)
        covered = self.covered()
        team = float(p.team_reward(covered))
        rewards = team + np.where(collided, p.collision_reward, 0.0)
        s = self.stats
        s["ep_return"] = s["ep_return"] + rewards
        s["ep_collisions"] += pairs
        s["ep_coverage_sum"] += covered.mean()
        s["ep_steps"] += 1
        count = int(covered.sum())
        infos = [{"success": bool(covered.all()), "coverage": float(covered.mean()), "covered": count,
                  "collided": bool(collided[i]), "reward_team": team} for i in range(n)]
        return rewards, infos

    def _summary(self) -> dict[str, Any]:
        covered, s = self.covered(), self.stats
        return {"coverage": float(covered.mean()), "success": bool(covered.all()),
                "coverage_mean": s["ep_coverage_sum"] / max(s["ep_steps"], 1), "collisions": int(s["ep_collisions"]),
                "return": s["ep_return"].copy()}

    def render(self) -> np.ndarray | None:
        """The world scaled into the drawing square (its spawn square fills it)."""
        if self.render_mode is None:
            return super().render()
        half = max(self.params.agent_spawn, self.params.landmark_spawn) * 1.1
        entities = [*self.world.agents, *self.world.landmarks]
        saved = [(e.state.p_pos, e.size) for e in entities]
        try:
            for e in entities:
                e.state.p_pos, e.size = e.state.p_pos * (0.5 / half), e.size * (0.5 / half)
            return draw_world(self.world, rings=(self.params.cover_radius * 0.5 / half,))
        finally:
            for e, (pos, size) in zip(entities, saved, strict=True):
                e.state.p_pos, e.size = pos, size


def parallel_env(variant: str = "vacl", render_mode: str | None = None, max_cycles: int | None = None,
                 **fields: Any) -> SparseNavEnv:
    """A navigation variant ("vacl" or "spmarl", cmcl.envs.sparse_nav.VARIANTS) with any NavParams fields changed
    (num_agents=8, ...); max_cycles, when given, is its episode_length. Agents "agent_0".."agent_{N-1}"."""
    if max_cycles is not None:
        fields["episode_length"] = max_cycles
    return SparseNavEnv(sparse_nav.variant(variant, **fields), render_mode=render_mode)

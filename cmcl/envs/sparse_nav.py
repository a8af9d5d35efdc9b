"""All-or-nothing and gated sparse navigation: the world parameters, the initial states and the batched
numpy twin of `cmcl.envs.sparse_nav_v0` (the PettingZoo ParallelEnv the runs train through `env.factory`).

Two variants of cooperative navigation from the curriculum literature, where uniform replay has no dense signal:

* ``vacl`` -- VACL's all-or-nothing navigation (Chen et al., NeurIPS 2021;
  jiayu-ch15/Variational-Automatic-Curriculum-Learning envs/mpe/scenarios/simple_spread.py, its `share_reward`,
  `reward`, `get_info` and `observation`, with the spawn square [-3, 3]^2 of the hard task's `legal_region` in
  algorithm/autocurriculum.py): N agents of radius 0.1 and N landmarks uniform in [-3, 3]^2; a landmark is covered
  when some agent's centre is within 0.15 (agent size 0.1 + landmark size 0.05); every agent receives 0.4 at a step
  in which *every* landmark is covered, else 0, and -0.1 when it touches another agent; 70 steps; each landmark's
  entry in the observation starts with its covered bit.
* ``spmarl`` -- SPMARL's gated navigation (Zhao, Li, Pajarinen, ICML 2025; wenshuaizhao/spmarl
  envs/mpe/scenarios/simple_spread.py, its `global_reward` with `sparse_reward`): N = 8 agents of radius 0.15
  uniform in [-2, 2]^2, landmarks uniform in 0.8 x that square; every agent receives the number of landmarks some
  agent is within 0.13 of, or 0 when fewer than 4 are; no collision penalty; 25 steps.

Success (the held-out metric, the sources' all-or-nothing one): every landmark covered at the episode's final step
(VACL's `get_info` "success"; for SPMARL the same rule at its 0.13). Coverage: the covered fraction at the final step.

Differences from the sources, on purpose: the physics is mpe2's World (the project's, `cmcl.envs.batched_core`),
unbounded as in MPE (no walls), with continuous actions (force = action x 5, the project's navigation) rather than
the sources' 5-way discrete one; covered uses `<` throughout (VACL's `get_info` uses `<=`, its reward `<`); the
covered bits of the first observation are those of the initial state (VACL's start at 0).

Where it sits: rollout-speed twin of the ParallelEnv (tests/test_sparse_nav.py checks their parity on the same seeds
and actions); the presets configs/vacl_n4_maddpg.toml, vacl_n8_maddpg.toml and spmarl_n8_maddpg.toml train the
ParallelEnv through env.factory (cmcl.system builds a twin for the built-in tasks only).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from cmcl.envs.batched_core import BatchedWorld, strided_view
from cmcl.envs.common import check_float, check_int

RULES = ("all_or_nothing", "gated")


@dataclass(frozen=True)
class NavParams:
    """One sparse navigation world: N agents and N landmarks in the open plane (lengths in MPE units)."""

    num_agents: int = 4
    agent_radius: float = 0.1
    landmark_radius: float = 0.05  # for drawing only: landmarks do not collide (VACL's cover 0.15 = 0.1 + this)
    cover_radius: float = 0.15  # a landmark is covered when some agent's centre is closer than this
    agent_spawn: float = 3.0  # agents uniform in [-agent_spawn, agent_spawn]^2
    landmark_spawn: float = 3.0  # landmarks uniform in [-landmark_spawn, landmark_spawn]^2
    sensitivity: float = 5.0  # force = action x sensitivity
    rule: str = "all_or_nothing"  # "all_or_nothing": cover_reward iff every landmark is covered; "gated": below
    cover_reward: float = 0.4  # all_or_nothing: the team reward; gated: per covered landmark
    gate: int = 0  # gated: the team reward is 0 while fewer than `gate` landmarks are covered
    collision_reward: float = -0.1  # to an agent touching another agent, at most once per step
    cover_bits: bool = True  # each landmark's observation entry starts with its covered bit
    episode_length: int = 70

    def __post_init__(self) -> None:
        check_int("num_agents", self.num_agents, 1)
        for name in ("agent_radius", "landmark_radius", "cover_radius", "agent_spawn", "landmark_spawn", "sensitivity"):
            check_float(name, getattr(self, name))
        for name in ("cover_reward", "collision_reward"):
            check_float(name, getattr(self, name), -np.inf)
        check_int("gate", self.gate, 0)
        check_int("episode_length", self.episode_length, 1)
        if self.rule not in RULES:
            raise ValueError(f"rule must be one of {RULES}, got {self.rule!r}")
        object.__setattr__(self, "cover_bits", bool(self.cover_bits))

    @property
    def num_landmarks(self) -> int:
        return self.num_agents

    @property
    def landmark_width(self) -> int:
        """Columns per landmark: (covered bit,) dx, dy."""
        return 3 if self.cover_bits else 2

    @property
    def obs_dim(self) -> int:
        """[vel(2), pos(2), per landmark ([covered], dx, dy), other agents' rel pos (2(N-1))]."""
        return 4 + self.landmark_width * self.num_landmarks + 2 * (self.num_agents - 1)

    def team_reward(self, covered: np.ndarray, gate: np.ndarray | None = None) -> np.ndarray:
        """The shared reward of worlds whose landmarks are `covered` (bool[..., L]) -> float64[...]; `gate`
        (landmarks, broadcast against [...]): each world's own gate, default this world's."""
        count = np.sum(covered, axis=-1)
        if self.rule == "all_or_nothing":
            return np.where(count == self.num_landmarks, self.cover_reward, 0.0)
        return np.where(count >= (self.gate if gate is None else gate), self.cover_reward * count, 0.0)


VARIANTS = {
    "vacl": NavParams(),
    "spmarl": NavParams(num_agents=8, agent_radius=0.15, cover_radius=0.13, agent_spawn=2.0, landmark_spawn=1.6,
                        rule="gated", cover_reward=1.0, gate=4, collision_reward=0.0, cover_bits=False,
                        episode_length=25),
}


def variant(name: str, **fields: Any) -> NavParams:
    """The world of a named variant ("vacl", "spmarl") with any fields changed (num_agents=8, ...)."""
    if name not in VARIANTS:
        raise ValueError(f"variant must be one of {sorted(VARIANTS)}, got {name!r}")
    return replace(VARIANTS[name], **fields)


def sample_nav(rng: np.random.Generator, n: int, p: NavParams, scale: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
    """Initial state of n worlds: (agents float64[n, N, 2], landmarks float64[n, L, 2]), each uniform in its square
    (overlaps allowed, as in the sources); `scale` float64[n]: each world's spawn_scale (its squares' half-widths
    times it; cmcl.envs.world_settings), default 1. The draws are the same whatever the scale."""
    a, lm = p.agent_spawn, p.landmark_spawn
    if scale is not None:
        a, lm = a * scale[:, None, None], lm * scale[:, None, None]
    agents = rng.uniform(-a, a, (n, p.num_agents, 2))
    landmarks = rng.uniform(-lm, lm, (n, p.num_landmarks, 2))
    return agents, landmarks


def nav_settings(p: NavParams, name: str, value: float) -> dict[str, Any]:
    """The NavParams fields that world setting `name` = `value` (cmcl.envs.world_settings) changes in `p`, the
    variant's own world: spawn_scale scales both spawn squares."""
    if name == "spawn_scale":
        return {"agent_spawn": p.agent_spawn * value, "landmark_spawn": p.landmark_spawn * value}
    if name == "gate":
        return {"gate": int(value)}
    if name == "cover_radius":
        return {"cover_radius": float(value)}
    raise ValueError(f"world setting {name!r}: navigation's are spawn_scale, cover_radius, gate")


class BatchedSparseNav(BatchedWorld):
    """B sparse navigation worlds without walls. obs [B, N, obs_dim] (NavParams.obs_dim).

    info per step: collided bool[B, N], covered int64[B, N] (landmarks covered, the same for every agent),
    reward_team [B, N]; info["episode"] over the M finished worlds: coverage float64[M] (final step), success
    bool[M] (every landmark covered at the final step), coverage_mean float64[M], collisions int64[M] (agent pairs
    in contact, summed over steps), return float64[M, N].
    """

    stat_keys = ("ep_return", "ep_collisions", "ep_coverage_sum", "ep_steps")

    def __init__(self, num_envs: int, params: NavParams | None = None, seed: int | np.random.Generator | None = None,
                 auto_reset: bool = False, dtype: Any = np.float32) -> None:
        self.params = p = NavParams() if params is None else params
        n, num_l = p.num_agents, p.num_landmarks
        self.obs_dims = (p.obs_dim,) * n
        self.teams = {"agent": list(range(n))}
        super().__init__(num_envs, radii=np.full(n, p.agent_radius), accels=np.full(n, p.sensitivity),
                         max_speeds=None, num_landmarks=num_l, episode_length=p.episode_length, seed=seed,
                         auto_reset=auto_reset, dtype=dtype)
        self._wall = np.full_like(self._wall, np.inf)  # the open plane: no wall ever clamps
        self._neg_wall = -self._wall
        b, dt, obs, w = self.num_envs, self.dtype, self._obs, p.landmark_width
        self._o_vel, self._o_pos = obs[:, 0:2], obs[:, 2:4]
        block = strided_view(obs[:, 4 : 4 + w * num_l], (n, num_l, w, b))
        self._o_bit = block[:, :, 0] if p.cover_bits else None  # [N, L, B]
        self._o_lm = block[:, :, w - 2 :]  # landmark_l - pos_i [N, L, 2, B]
        self._o_oth = strided_view(obs[:, 4 + w * num_l :], (n, n - 1, 2, b))
        self._d = np.empty((n, num_l, b), dt)
        self._covered = np.zeros((num_l, b), bool)
        self._collided = np.zeros((n, b), bool)
        self._touches = np.empty((n, b), dt)
        # each world's settings in force (cmcl.envs.world_settings) and the ones its next reset takes
        self._settings = {"spawn_scale": np.ones(b), "cover_radius": np.full(b, p.cover_radius, dt),
                          "gate": np.full(b, p.gate, np.int64)}
        self._next_settings = {k: v.copy() for k, v in self._settings.items()}
        self._resetting = np.arange(b)
        self.reset()

    def set_world_settings(self, name: str, idx: np.ndarray, values: np.ndarray) -> None:
        """World setting `name` (spawn_scale, cover_radius, gate) = values float64[M] for the worlds idx int64[M],
        from each one's next reset on."""
        if name not in self._next_settings:
            raise ValueError(f"world setting {name!r}: navigation's are {sorted(self._next_settings)}")
        self._next_settings[name][idx] = values

    def world_settings(self) -> dict[str, np.ndarray]:
        """Copies of each world's settings in force: spawn_scale float64[B], cover_radius [B], gate int64[B]."""
        return {k: v.copy() for k, v in self._settings.items()}

    def _reset_worlds(self, idx: np.ndarray) -> None:
        for key, value in self._settings.items():
            value[idx] = self._next_settings[key][idx]
        self._resetting = idx
        super()._reset_worlds(idx)

    def _sample(self, rng: np.random.Generator, count: int) -> tuple[np.ndarray, np.ndarray]:
        return sample_nav(rng, count, self.params, self._settings["spawn_scale"][self._resetting])

    def _observe(self) -> None:
        np.copyto(self._o_vel, self._vel)
        np.copyto(self._o_pos, self._pos)
        rel = self._o_lm
        np.subtract(self._lm[None], self._pos[:, None], out=rel)
        np.sqrt(np.square(rel[:, :, 0]) + np.square(rel[:, :, 1]), out=self._d)
        np.less(self._d.min(axis=0), self._settings["cover_radius"], out=self._covered)
        if self._o_bit is not None:
            np.copyto(self._o_bit, self._covered[None])
        np.take(self._pos, self._others, axis=0, out=self._o_oth)
        self._o_oth -= self._pos[:, None]

    def _score(self) -> dict[str, np.ndarray]:
        p = self.params
        np.copyto(self._pcontact_f, self._pcontact)
        np.matmul(self._touch, self._pcontact_f, out=self._touches)
        np.greater(self._touches, 0.5, out=self._collided)
        team = p.team_reward(self._covered.T, self._settings["gate"])  # [B]
        np.copyto(self._rew, team[None] + np.where(self._collided, p.collision_reward, 0.0))
        count = self._covered.sum(axis=0)
        s = self._stats
        s["ep_return"] += self._rew
        s["ep_collisions"] += self._pcontact.sum(axis=0)
        s["ep_coverage_sum"] += count / self.num_landmarks
        s["ep_steps"] += 1
        return {"collided": self._collided, "covered": np.broadcast_to(count, self._collided.shape),
                "reward_team": np.broadcast_to(team, self._collided.shape)}

    def _episode(self, idx: np.ndarray) -> dict[str, np.ndarray]:
        covered = self._covered[:, idx]  # [L, M]
        s = self._stats
        return {
            "coverage": covered.mean(axis=0) if self.num_landmarks else np.ones(len(idx)),
            "success": covered.all(axis=0),
            "coverage_mean": s["ep_coverage_sum"][idx] / np.maximum(s["ep_steps"][idx], 1),
            "collisions": s["ep_collisions"][idx],
            "return": s["ep_return"][:, idx].T.copy(),
        }

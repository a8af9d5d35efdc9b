"""Batched twin of `sparse_spread_v0`: B navigation worlds stepped at once in numpy.

Where it sits: the rollout workers' navigation environment (exported by `cmcl.envs.batched`); it has
the dynamics, observations, rewards and episode statistics of the PettingZoo version
(tests/test_env_parity.py). Rules in ALGORITHM.md §6.1 and the module docstring of
`cmcl.envs.sparse_spread_v0`; physics in `cmcl.envs.batched_core`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cmcl.envs import metrics
from cmcl.envs.batched_core import BatchedWorld, strided_view
from cmcl.envs.params import EPISODE_LENGTH, SpreadParams
from cmcl.envs.spawn import sample_agent_tags, sample_spread


class BatchedSparseSpread(BatchedWorld):
    """B sparse navigation worlds. obs [B, N, 4N + 2]: [vel, pos, landmark rel (2N), other agents rel (2(N-1))],
    with params.agent_tags then [own tag, other agents' tags (N-1)] ([B, N, 5N + 2]; tags drawn at each episode
    start, in get_state / set_state as "tags" [B, N]).

    info per step: wall_hit, collided, covering bool[B, N], reward_unshared [B, N]; info["episode"]
    over the M finished worlds: coverage float64[M] (final step), success bool[M] (final step),
    coverage_mean float64[M] (per-step average), collisions int64[M] (agent pairs in contact, summed
    over steps), wall_hits int64[M] (agent-steps clamped), return float64[M, N] (unshared returns).
    """

    stat_keys = ("ep_return", "ep_wall_hits", "ep_collisions", "ep_coverage_sum", "ep_steps")

    def __init__(
        self,
        num_envs: int,
        params: SpreadParams | None = None,
        episode_length: int = EPISODE_LENGTH,
        seed: int | np.random.Generator | None = None,
        auto_reset: bool = False,
        dtype: Any = np.float32,
    ) -> None:
        """`params`: the world (default `SpreadParams()`); `episode_length` steps per episode."""
        self.params = p = SpreadParams() if params is None else params
        n, num_l = p.num_agents, p.num_landmarks
        self.obs_dims = (p.obs_dim,) * n
        self.teams = {"agent": list(range(n))}
        super().__init__(
            num_envs,
            radii=np.full(n, p.agent_radius),
            accels=np.full(n, p.sensitivity),
            max_speeds=None,
            num_landmarks=num_l,
            episode_length=episode_length,
            seed=seed,
            auto_reset=auto_reset,
            dtype=dtype,
        )
        b, dt, obs = self.num_envs, self.dtype, self._obs
        self._o_vel, self._o_pos = obs[:, 0:2], obs[:, 2:4]
        self._o_lm = strided_view(obs[:, 4 : 4 + 2 * num_l], (n, num_l, 2, b))  # landmark_l - pos_i
        self._o_oth = strided_view(obs[:, 4 + 2 * num_l : p.tags_at], (n, n - 1, 2, b))  # pos_j - pos_i, j != i
        # agent tags (p.agent_tags): u [N, B], drawn at each episode start; obs [u_i, u_j for j != i]
        self._tags = np.zeros((n, b), dt) if p.agent_tags else None
        if p.agent_tags:
            self._o_tag, self._o_tags = obs[:, p.tags_at], obs[:, p.tags_at + 1 :]  # [N, B], [N, N-1, B]
        self._d, self._dw = np.empty((n, num_l, b), dt), np.empty((n, num_l, b), dt)
        self._mind = np.empty((num_l, b), dt)
        self._covered = np.zeros((num_l, b), bool)
        self._ismin, self._seen = np.empty((n, num_l, b), bool), np.empty((n, num_l, b), bool)
        rank_dtype = next((t for t in (np.uint8, np.uint16, np.uint32, np.uint64) if np.iinfo(t).bits >= n), None)
        self._rank = None if rank_dtype is None else (np.uint64(1) << np.arange(n - 1, -1, -1, dtype=np.uint64))
        if rank_dtype is not None:
            self._rank = self._rank.astype(rank_dtype).reshape(n, 1, 1)
            self._ranked, self._top = np.empty((n, num_l, b), rank_dtype), np.empty((num_l, b), rank_dtype)
        self._covering, self._collided = np.zeros((n, b), bool), np.zeros((n, b), bool)
        self._penal = np.zeros((n, b), bool)
        self._touches, self._nb = np.empty((n, b), dt), np.empty((n, b), dt)
        self._unshared, self._team = np.zeros((n, b), dt), np.empty(b, dt)
        self._count = np.empty(b, np.int64)
        self.reset()

    def _sample(self, rng: np.random.Generator, count: int) -> tuple[np.ndarray, np.ndarray]:
        return sample_spread(rng, count, self.params)

    def _draw_episode(self, rng: np.random.Generator, idx: np.ndarray) -> None:
        if self._tags is not None:
            self._tags[:, idx] = sample_agent_tags(rng, len(idx), self.params).T

    def _episode_constants(self) -> dict[str, np.ndarray]:
        return {} if self._tags is None else {"tags": self._tags}

    def _observe(self) -> None:
        np.copyto(self._o_vel, self._vel)
        np.copyto(self._o_pos, self._pos)
        np.subtract(self._lm[None], self._pos[:, None], out=self._o_lm)
        np.take(self._pos, self._others, axis=0, out=self._o_oth)
        self._o_oth -= self._pos[:, None]
        if self._tags is not None:
            np.copyto(self._o_tag, self._tags)
            np.take(self._tags, self._others, axis=0, out=self._o_tags)

    def _score(self) -> dict[str, np.ndarray]:
        p = self.params
        d, dw, ismin, seen = self._d, self._dw, self._ismin, self._seen
        # agent-landmark distances [N, L, B]; the closest agent (lowest index on ties) covers within 0.1
        np.multiply(self._o_lm[:, :, 0], self._o_lm[:, :, 0], out=d)
        np.multiply(self._o_lm[:, :, 1], self._o_lm[:, :, 1], out=dw)
        d += dw
        np.sqrt(d, out=d)
        np.min(d, axis=0, out=self._mind)
        np.less(self._mind, p.cover_radius, out=self._covered)
        np.equal(d, self._mind[None], out=ismin)
        if self._rank is not None:  # keep the lowest index among tied minima: weights 2^(N-1-i), take the max
            np.multiply(ismin, self._rank, out=self._ranked)
            np.max(self._ranked, axis=0, out=self._top)
            np.equal(self._ranked, self._top[None], out=ismin)
        else:
            np.logical_or.accumulate(ismin, axis=0, out=seen)
            np.logical_not(seen[:-1], out=seen[:-1])
            np.logical_and(ismin[1:], seen[:-1], out=ismin[1:])
        np.logical_and(ismin, self._covered[None], out=ismin)
        np.any(ismin, axis=1, out=self._covering)
        # agent-agent contact (self excluded by construction of the pairs)
        np.copyto(self._pcontact_f, self._pcontact)
        np.matmul(self._touch, self._pcontact_f, out=self._touches)
        np.greater(self._touches, 0.5, out=self._collided)
        # C1 + C2, at most once each per agent and step
        np.logical_or(self._collided, self._wall_hit, out=self._penal)
        u = self._unshared
        np.multiply(self._penal, p.collision_reward, out=u)
        np.multiply(self._covering, p.cover_reward, out=self._nb)
        u += self._nb
        if p.shared_reward:
            np.sum(u, axis=0, out=self._team)
            np.copyto(self._rew, self._team[None])
        else:
            np.copyto(self._rew, u)
        s, c = self._stats, self._count
        s["ep_return"] += u
        np.sum(self._wall_hit, axis=0, out=c)
        s["ep_wall_hits"] += c
        np.sum(self._pcontact, axis=0, out=c)
        s["ep_collisions"] += c
        np.sum(self._covered, axis=0, out=c)
        s["ep_coverage_sum"] += c / self.num_landmarks
        s["ep_steps"] += 1
        return {
            "wall_hit": self._wall_hit,
            "collided": self._collided,
            "covering": self._covering,
            "reward_unshared": u,
        }

    def _episode(self, idx: np.ndarray) -> dict[str, np.ndarray]:
        cover = (self._d[..., idx] < self.params.cover_radius).transpose(2, 0, 1)  # [M, N, L]
        s = self._stats
        return {
            "coverage": metrics.coverage_rate(cover),
            "success": metrics.success(cover),
            "coverage_mean": s["ep_coverage_sum"][idx] / np.maximum(s["ep_steps"][idx], 1),
            "collisions": s["ep_collisions"][idx],
            "wall_hits": s["ep_wall_hits"][idx],
            "return": s["ep_return"][:, idx].T.copy(),
        }

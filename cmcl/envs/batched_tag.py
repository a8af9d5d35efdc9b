"""Batched twin of `sparse_tag_v0`: B predator-prey worlds stepped at once in numpy.

Where it sits: the rollout workers' predator-prey environment (exported by `cmcl.envs.batched`); it has
the dynamics, observations, rewards and episode statistics of the PettingZoo version
(tests/test_env_parity.py). Rules in ALGORITHM.md §6.2 and the module docstring of
`cmcl.envs.sparse_tag_v0`; physics in `cmcl.envs.batched_core`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cmcl.envs import metrics
from cmcl.envs.batched_core import BatchedWorld, softplus_contact, strided_view
from cmcl.envs.params import EPISODE_LENGTH, TagParams
from cmcl.envs.spawn import sample_tag


class BatchedSparseTag(BatchedWorld):
    """B sparse predator-prey worlds; agents 0..m-1 are predators, m..N-1 prey.

    Defaults: the calibrated world of ALGORITHM.md §6.2 (see `TagParams`). Rewards per step [B, N]:
    each (predator, prey) pair in contact gives +capture_reward to that predator and -capture_reward to
    that prey (with shared_reward=True every predator gets +capture_reward per pair in the world), plus
    wall_reward to each agent clamped at a wall.

    obs [B, N, obs_dim] with obs_dim = max(obs_dims): [vel, pos, obstacle rel (2O), other agents rel
    (2(N-1)), other prey's velocities]; prey rows are zero-padded by 2 at the end (obs_dims[i] is the
    true length). info per step: wall_hit bool[B, N], captures int64[B, N] (contact pairs involving the
    agent); info["episode"] over the M finished worlds: captures int64[M] (predator-prey pairs in
    contact, summed over steps), predator_win bool[M], wall_hits int64[M], return float64[M, N].
    """

    stat_keys = ("ep_return", "ep_wall_hits", "ep_captures", "ep_steps")

    def __init__(
        self,
        num_envs: int,
        params: TagParams | None = None,
        episode_length: int = EPISODE_LENGTH,
        seed: int | np.random.Generator | None = None,
        auto_reset: bool = False,
        dtype: Any = np.float32,
    ) -> None:
        """`params`: the world (default `TagParams()`, the calibrated one); `episode_length` steps per episode."""
        self.params = p = TagParams() if params is None else params
        m, q, o, n = p.num_predators, p.num_prey, p.num_obstacles, p.num_agents
        self.obs_dims = p.obs_dims
        self.teams = {"predator": list(range(m)), "prey": list(range(m, n))}
        super().__init__(
            num_envs,
            radii=p.radii,
            accels=p.accels,
            max_speeds=p.max_speeds,
            num_landmarks=o,
            episode_length=episode_length,
            seed=seed,
            auto_reset=auto_reset,
            dtype=dtype,
        )
        b, dt, obs = self.num_envs, self.dtype, self._obs
        off_a, off_v = 4 + 2 * o, 4 + 2 * o + 2 * (n - 1)
        self._o_vel, self._o_pos = obs[:, 0:2], obs[:, 2:4]
        self._o_ob = strided_view(obs[:, 4:off_a], (n, o, 2, b))  # obstacle_o - pos_i
        self._o_oth = strided_view(obs[:, off_a:off_v], (n, n - 1, 2, b))  # pos_j - pos_i, j != i
        self._o_pv = strided_view(obs[:m, off_v : off_v + 2 * q], (m, q, 2, b))  # predators: all prey vel
        self._o_qv = strided_view(obs[m:, off_v : off_v + 2 * (q - 1)], (q, q - 1, 2, b))  # prey: other prey
        self._other_prey = np.array([[j for j in range(q) if j != i] for i in range(q)], np.intp).reshape(q, q - 1)
        # agent-obstacle contact (obstacles immovable: force on the agent only)
        self._ob_dmin = (p.radii[:, None] + p.obstacle_radius).astype(dt).reshape(n, 1, 1)
        self._ob_dist, self._ob_gap = np.ones((n, o, b), dt), np.empty((n, o, b), dt)
        self._ob_work, self._ob_sq = np.empty((n, o, b), dt), np.empty((n, o, b), dt)
        self._ob_force, self._ob_sum = np.empty((n, o, 2, b), dt), np.empty((n, 2, b), dt)
        # predator-prey pairs in (predator, prey) order, as indices into the agent pair list
        pair_of = {(int(i), int(j)): k for k, (i, j) in enumerate(zip(self._pi, self._pj, strict=True))}
        self._pp = np.array([pair_of[(k, m + j)] for k in range(m) for j in range(q)], np.intp)
        self._pp_contact = np.zeros((m, q, b), bool)
        self._prey_hits, self._pred_hits = np.zeros((q, b), np.int64), np.zeros((m, b), np.int64)
        self._captures, self._count = np.zeros(b, np.int64), np.empty(b, np.int64)
        self._involved = np.zeros((n, b), np.int64)
        self._nb = np.empty((n, b), dt)
        self.reset()

    def _sample(self, rng: np.random.Generator, count: int) -> tuple[np.ndarray, np.ndarray]:
        return sample_tag(rng, count, self.params)

    def _observe(self) -> None:
        m, v = self.params.num_predators, self._vel
        np.copyto(self._o_vel, v)
        np.copyto(self._o_pos, self._pos)
        np.subtract(self._lm[None], self._pos[:, None], out=self._o_ob)
        np.take(self._pos, self._others, axis=0, out=self._o_oth)
        self._o_oth -= self._pos[:, None]
        np.copyto(self._o_pv, v[m:][None])
        if self.params.num_prey > 1:
            np.take(v[m:], self._other_prey, axis=0, out=self._o_qv)
        # agent-obstacle distances [N, O, B], kept for the next step's contact forces
        np.multiply(self._o_ob[:, :, 0], self._o_ob[:, :, 0], out=self._ob_dist)
        np.multiply(self._o_ob[:, :, 1], self._o_ob[:, :, 1], out=self._ob_sq)
        self._ob_dist += self._ob_sq
        np.sqrt(self._ob_dist, out=self._ob_dist)

    def _extra_forces(self, force: np.ndarray) -> None:
        """force [N, 2, B] += sum over obstacles of mpe2's contact force on the agent."""
        if self.params.num_obstacles == 0:
            return
        np.subtract(self._ob_dmin, self._ob_dist, out=self._ob_gap)
        softplus_contact(self._ob_gap, self._ob_dist, self._ob_work)
        np.multiply(self._o_ob, self._ob_gap[:, :, None, :], out=self._ob_force)  # -(force): o_ob = obstacle - pos
        np.sum(self._ob_force, axis=1, out=self._ob_sum)
        force -= self._ob_sum

    def _score(self) -> dict[str, np.ndarray]:
        p, m = self.params, self.params.num_predators
        contact = self._pp_contact
        np.take(self._pcontact, self._pp, axis=0, out=strided_view(contact, (len(self._pp), self.num_envs)))
        np.sum(contact, axis=(0, 1), out=self._captures)
        np.sum(contact, axis=0, out=self._prey_hits)
        np.sum(contact, axis=1, out=self._pred_hits)
        r = self._rew
        np.multiply(self._wall_hit, p.wall_reward, out=r)
        if p.shared_reward:  # every predator: +capture_reward per pair in contact in its world
            np.multiply(self._captures, p.capture_reward, out=self._nb[0])
            r[:m] += self._nb[0]
        else:  # each predator: +capture_reward per prey it touches
            np.multiply(self._pred_hits, p.capture_reward, out=self._nb[:m])
            r[:m] += self._nb[:m]
        np.multiply(self._prey_hits, p.capture_reward, out=self._nb[m:])
        r[m:] -= self._nb[m:]
        self._involved[:m] = self._pred_hits
        self._involved[m:] = self._prey_hits
        s, c = self._stats, self._count
        s["ep_return"] += r
        np.sum(self._wall_hit, axis=0, out=c)
        s["ep_wall_hits"] += c
        s["ep_captures"] += self._captures
        s["ep_steps"] += 1
        return {"wall_hit": self._wall_hit, "captures": self._involved}

    def _episode(self, idx: np.ndarray) -> dict[str, np.ndarray]:
        s = self._stats
        captures = s["ep_captures"][idx]
        return {
            "captures": captures,
            "predator_win": metrics.predator_win(captures),
            "wall_hits": s["ep_wall_hits"][idx],
            "return": s["ep_return"][:, idx].T.copy(),
        }

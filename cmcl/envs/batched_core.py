"""Batched numpy physics shared by the twins: B mpe2 worlds with walls, stepped with no Python loops.

Where it sits: base class of `BatchedSparseSpread` and `BatchedSparseTag` (cmcl/envs/batched.py),
which rollout workers step instead of B PettingZoo envs. It reproduces mpe2's `World.step` exactly
(ALGORITHM.md §6): action force, soft contact forces between collidable pairs, integration
(position with the old velocity, damping, force * dt / mass, max-speed clamp), then the walls.

Internal layout is batch-last (`pos: [N, 2, B]`) so that every numpy call runs long contiguous
inner loops over the worlds; the public API is batch-first (`[B, N, ...]`) and converts once per
step. All buffers are preallocated; the hot path uses `out=` and in-place operations.
Only agent-agent pairs (precomputed index arrays I < J) and, in subclasses, agent-obstacle pairs
are tested for contact.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cmcl.envs.common import (
    ARENA_HALF,
    CONTACT_FORCE,
    CONTACT_MARGIN,
    DAMPING,
    DT,
    check_dtype,
    check_int,
    check_state_arrays,
    make_rng,
)

SOFTPLUS_CUT = 50.0  # softplus(x) < 2e-22 for x < -50: computing it exactly only hits slow denormal paths
SOFTPLUS_TOP = 80.0  # softplus(x) = x to float precision for x > 80 (and exp(88) overflows float32)
MIN_DIST = 1e-20  # distances below this only occur as exact zeros (agents clamped into one corner)


def strided_view(arr: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """A reshaped *view* of `arr` (raises instead of silently copying)."""
    view = arr.view()
    view.shape = shape
    return view


def softplus_contact(gap: np.ndarray, dist: np.ndarray, work: np.ndarray) -> None:
    """In place: gap <- contact_force * k * log(1 + exp(gap / k)) / dist (mpe2's force per unit delta).

    gap: [..., B] = dist_min - dist, overwritten with the weight w such that force = w * delta;
    dist: [..., B] centre distances; work: scratch like gap. mpe2 uses logaddexp(0, x), which numpy
    computes slowly in float32; here softplus(x) = max(x, log1p(exp(clip(x, -50, 80)))): exact to
    rounding for x in [-50, 80]; beyond, the change is below exp(-50) * k * 100 ~ 2e-23 force units
    (x < -50; exp/log1p of underflowing values are also 10-20x slower) or nil (x > 80: softplus = x).
    Coincident discs (dist = 0, delta = 0) get a finite weight, hence zero force, where mpe2 would
    produce NaN (see pz_base.WalledWorld).
    """
    np.divide(gap, CONTACT_MARGIN, out=gap)
    np.clip(gap, -SOFTPLUS_CUT, SOFTPLUS_TOP, out=work)
    np.exp(work, out=work)
    np.log1p(work, out=work)
    np.maximum(gap, work, out=gap)
    np.multiply(gap, CONTACT_MARGIN * CONTACT_FORCE, out=gap)
    np.maximum(dist, MIN_DIST, out=work)
    np.divide(gap, work, out=gap)


class BatchedWorld:
    """B worlds of N agents and L landmarks; subclasses add observations, rewards and statistics."""

    obs_dims: tuple[int, ...] = ()
    act_dim = 2
    teams: dict[str, list[int]] = {}
    stat_keys: tuple[str, ...] = ()

    def __init__(
        self,
        num_envs: int,
        radii: np.ndarray,
        accels: np.ndarray,
        max_speeds: np.ndarray | None,
        num_landmarks: int,
        episode_length: int,
        seed: int | np.random.Generator | None,
        auto_reset: bool,
        dtype: Any,
    ) -> None:
        self.num_envs = b = check_int("num_envs", num_envs, 1)
        self.episode_length = check_int("episode_length", episode_length, 1)
        self.dtype = check_dtype(dtype)
        self.auto_reset = bool(auto_reset)
        self._rng = make_rng(seed)
        n, dt = len(radii), self.dtype
        self.num_agents = n
        self.num_landmarks = num_landmarks
        self.obs_dim = max(self.obs_dims)
        self.radii = np.asarray(radii, dtype=np.float64)
        self._accel = np.asarray(accels, dtype=dt).reshape(n, 1, 1)
        self._wall = (ARENA_HALF - self.radii).astype(dt).reshape(n, 1, 1)
        self._neg_wall = -self._wall
        self._max_speed = None if max_speeds is None else np.asarray(max_speeds, dtype=dt).reshape(n, 1)
        # agent-agent pairs i < j, force +f on i and -f on j via an incidence matrix [N, P]
        self._pi, self._pj = (a.astype(np.intp) for a in np.triu_indices(n, 1))
        p = len(self._pi)
        self._pair_dmin = (self.radii[self._pi] + self.radii[self._pj]).astype(dt).reshape(p, 1)
        self._incidence = np.zeros((n, p), dtype=dt)
        self._incidence[self._pi, np.arange(p)] = 1.0
        self._incidence[self._pj, np.arange(p)] = -1.0
        self._touch = np.abs(self._incidence)
        self._others = np.array([[j for j in range(n) if j != i] for i in range(n)], dtype=np.intp).reshape(n, n - 1)
        # state and scratch, all batch-last
        self._pos, self._vel = np.zeros((n, 2, b), dt), np.zeros((n, 2, b), dt)
        self._lm = np.zeros((num_landmarks, 2, b), dt)
        self._t = np.zeros(b, np.int64)
        self._force, self._tmp = np.empty((n, 2, b), dt), np.empty((n, 2, b), dt)
        self._hitc, self._nhit = np.empty((n, 2, b), bool), np.empty((n, 2, b), bool)
        self._wall_hit = np.zeros((n, b), bool)
        self._speed, self._speed2 = np.empty((n, b), dt), np.empty((n, b), dt)
        self._ti, self._tj = np.empty((p, 2, b), dt), np.empty((p, 2, b), dt)
        self._pdelta, self._pforce = np.zeros((p, 2, b), dt), np.empty((p, 2, b), dt)
        self._pdist, self._pgap, self._pwork = np.ones((p, b), dt), np.empty((p, b), dt), np.empty((p, b), dt)
        self._pcontact, self._pcontact_f = np.zeros((p, b), bool), np.zeros((p, b), dt)
        self._obs = np.zeros((n, self.obs_dim, b), dt)
        self._rew = np.zeros((n, b), dt)
        self._empty_episode: dict[str, np.ndarray] | None = None
        self._stats = {k: self._new_stat(k) for k in self.stat_keys}  # ep_return [N, B], others [B]

    def _new_stat(self, key: str) -> np.ndarray:
        """Zeroed accumulator: ep_return float64[N, B], ep_*_sum float64[B], counters int64[B]."""
        if key == "ep_return":
            return np.zeros((self.num_agents, self.num_envs))
        return np.zeros(self.num_envs, np.float64 if key.endswith("_sum") else np.int64)

    # ----- subclass hooks ---------------------------------------------------------------------
    def _sample(self, rng: np.random.Generator, count: int) -> tuple[np.ndarray, np.ndarray]:
        """(agent positions float64[count, N, 2], landmark positions float64[count, L, 2])."""
        raise NotImplementedError

    def _extra_forces(self, force: np.ndarray) -> None:
        """Add non-agent contact forces (obstacles) to force [N, 2, B] from the cached geometry."""

    def _observe(self) -> None:
        """Fill self._obs [N, obs_dim, B] from the current state (after _geometry)."""
        raise NotImplementedError

    def _draw_episode(self, rng: np.random.Generator, idx: np.ndarray) -> None:
        """Per-episode draws beyond the initial state for the worlds idx (int[M]), after `_sample` from the same
        generator (navigation's agent tags); none by default."""

    def _episode_constants(self) -> dict[str, np.ndarray]:
        """Per-episode constants beyond the physical state, as their batch-last buffers [..., B] (navigation's agent
        tags "tags" [N, B]): get_state returns them batch-first, set_state requires and loads them. None by default."""
        return {}

    def _score(self) -> dict[str, np.ndarray]:
        """Fill self._rew [N, B] and update self._stats; return per-step infos as [N, B] arrays."""
        raise NotImplementedError

    def _episode(self, idx: np.ndarray) -> dict[str, np.ndarray]:
        """Per-episode statistics of the worlds idx (int[M]) whose episode ended this step."""
        raise NotImplementedError

    def _no_episodes(self) -> dict[str, np.ndarray]:
        """The "episode" dict for a step in which no episode ended: the same keys, zero-length arrays."""
        if self._empty_episode is None:
            self._empty_episode = self._episode(np.zeros(0, np.intp))
        return {k: v.copy() for k, v in self._empty_episode.items()}

    # ----- physics ----------------------------------------------------------------------------
    def _geometry(self) -> None:
        """Pair deltas pos_i - pos_j [P, 2, B] and distances [P, B] of the current positions."""
        np.take(self._pos, self._pi, axis=0, out=self._ti)
        np.take(self._pos, self._pj, axis=0, out=self._tj)
        np.subtract(self._ti, self._tj, out=self._pdelta)
        d, w = self._pdist, self._pwork
        np.multiply(self._pdelta[:, 0], self._pdelta[:, 0], out=d)
        np.multiply(self._pdelta[:, 1], self._pdelta[:, 1], out=w)
        d += w
        np.sqrt(d, out=d)
        np.less(d, self._pair_dmin, out=self._pcontact)

    def _physics(self, actions: np.ndarray) -> None:
        """One mpe2 world step plus walls. actions: [B, N, 2] finite, any float dtype."""
        f, tmp, v, pos = self._force, self._tmp, self._vel, self._pos
        np.copyto(f, actions.transpose(1, 2, 0), casting="unsafe")
        np.minimum(f, 1.0, out=f)  # clip to [-1, 1]
        np.maximum(f, -1.0, out=f)
        f *= self._accel
        if len(self._pi):  # soft contact between agents, from the positions before this step
            np.subtract(self._pair_dmin, self._pdist, out=self._pgap)
            softplus_contact(self._pgap, self._pdist, self._pwork)
            np.multiply(self._pdelta, self._pgap[:, None, :], out=self._pforce)
            flat = strided_view(tmp, (self.num_agents, -1))
            np.matmul(self._incidence, strided_view(self._pforce, (len(self._pi), -1)), out=flat)
            f += tmp
        self._extra_forces(f)
        np.multiply(v, DT, out=tmp)  # mpe2 order: position with the old velocity ...
        pos += tmp
        v *= 1.0 - DAMPING  # ... then damping ...
        np.multiply(f, DT, out=tmp)  # ... then force / mass * dt (mass 1) ...
        v += tmp
        if self._max_speed is not None:  # ... then the speed clamp
            s, s2 = self._speed, self._speed2
            np.multiply(v[:, 0], v[:, 0], out=s)
            np.multiply(v[:, 1], v[:, 1], out=s2)
            s += s2
            np.sqrt(s, out=s)
            np.maximum(s, self._max_speed, out=s)
            np.divide(self._max_speed, s, out=s)
            v *= s[:, None, :]
        np.abs(pos, out=tmp)  # walls: clamp, zero that velocity component, flag the hit
        np.greater(tmp, self._wall, out=self._hitc)
        np.minimum(pos, self._wall, out=pos)
        np.maximum(pos, self._neg_wall, out=pos)
        np.logical_not(self._hitc, out=self._nhit)
        np.multiply(v, self._nhit, out=v)
        np.logical_or(self._hitc[:, 0], self._hitc[:, 1], out=self._wall_hit)

    # ----- public API -------------------------------------------------------------------------
    def _check_actions(self, actions: Any) -> np.ndarray:
        a = np.asarray(actions)
        want = (self.num_envs, self.num_agents, self.act_dim)
        if a.shape != want:
            raise ValueError(f"actions must have shape (num_envs, num_agents, act_dim) = {want}, got {a.shape}")
        if a.dtype.kind not in "fiu":
            raise ValueError(f"actions must be a real numeric array, got dtype {a.dtype}")
        finite = np.isfinite(a)
        if not finite.all():
            b, i, c = np.argwhere(~finite)[0]
            raise ValueError(f"actions must be finite, got {a[b, i, c]} at [env {b}, agent {i}, dim {c}]")
        return a

    def _finish_obs(self) -> np.ndarray:
        """A fresh [B, N, obs_dim] copy of the observation buffer."""
        out = np.empty((self.num_envs, self.num_agents, self.obs_dim), self.dtype)
        np.copyto(out, self._obs.transpose(2, 0, 1))
        return out

    def observe(self) -> np.ndarray:
        """Current observations, dtype[B, N, obs_dim] (zero-padded past each agent's obs_dims[i])."""
        return self._finish_obs()

    def reset(self, seed: int | np.random.Generator | None = None) -> np.ndarray:
        """Start new episodes in all B worlds; returns obs dtype[B, N, obs_dim]. A seed re-seeds the generator."""
        if seed is not None:
            self._rng = make_rng(seed)
        self._reset_worlds(np.arange(self.num_envs))
        return self._finish_obs()

    def _reset_worlds(self, idx: np.ndarray) -> None:
        """Draw new initial states for the worlds idx (int[M]) and refresh geometry and observations."""
        agents, landmarks = self._sample(self._rng, len(idx))
        self._draw_episode(self._rng, idx)
        self._pos[..., idx] = agents.transpose(1, 2, 0)
        self._vel[..., idx] = 0.0
        self._lm[..., idx] = landmarks.transpose(1, 2, 0)
        self._t[idx] = 0
        for s in self._stats.values():
            s[..., idx] = 0
        self._geometry()
        self._observe()

    def step(self, actions: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Advance all B worlds by one step.

        actions: float[B, N, 2]; values outside [-1, 1] are clipped; NaN/inf or a wrong shape raise ValueError.
        Returns (obs dtype[B, N, obs_dim], rewards dtype[B, N], dones bool[B], info). `dones` marks the
        time limit (episode_length steps), never a terminal state: learners bootstrap there. info holds
        per-step arrays [B, N] ("wall_hit", ...), "episode_mask" bool[B], "terminated" bool[B] (always False here)
        and "episode", a dict of arrays
        over the M worlds whose episode ended now (in index order). With auto_reset, those worlds restart
        (the returned obs is their first observation) and info["final_obs"] dtype[B, N, obs_dim] is the
        observation after this step's action for all B: use it as next_obs. Returned arrays are fresh
        (never views of internal buffers); final_obs is obs itself when no world restarted.
        """
        a = self._check_actions(actions)
        if not self.auto_reset and (self._t >= self.episode_length).any():
            raise RuntimeError("an episode has ended (auto_reset=False): call reset() before step()")
        self._physics(a)
        self._geometry()
        self._observe()
        step_info = self._score()
        self._t += 1
        dones = self._t >= self.episode_length
        rewards = self._rew.T.copy()  # copies: ascontiguousarray would return a view when B = 1
        info: dict[str, Any] = {k: v.T.copy() for k, v in step_info.items()}
        info["episode_mask"] = dones
        info["terminated"] = np.zeros_like(dones)  # time limits only: every world bootstraps (ALGORITHM.md §2)
        idx = np.flatnonzero(dones)
        info["episode"] = self._episode(idx) if len(idx) else self._no_episodes()
        obs = self._finish_obs()
        if self.auto_reset:
            info["final_obs"] = obs  # the very same array as the returned obs when no world restarted
            if len(idx):
                self._reset_worlds(idx)
                obs = self._finish_obs()
        return obs, rewards, dones, info

    # ----- state ------------------------------------------------------------------------------
    def get_state(self) -> dict[str, np.ndarray]:
        """Copies: positions [B, N, 2], velocities [B, N, 2], landmarks [B, L, 2] (obstacles in tag),
        step int64[B] (steps taken in the episode), plus the episode accumulators (ep_*)."""
        state = {
            "positions": self._pos.transpose(2, 0, 1).copy(),
            "velocities": self._vel.transpose(2, 0, 1).copy(),
            "landmarks": self._lm.transpose(2, 0, 1).copy(),
            "step": self._t.copy(),
        }
        for k, v in self._stats.items():
            state[k] = v.T.copy()
        for k, v in self._episode_constants().items():
            state[k] = np.moveaxis(v, -1, 0).copy()
        return state

    def set_state(self, state: dict[str, Any]) -> np.ndarray:
        """Load a state of the get_state form (ep_* keys optional, zero if absent; the per-episode constants, such as
        navigation's "tags", required); returns obs [B, N, obs_dim]."""
        b, n, num_l = self.num_envs, self.num_agents, self.num_landmarks
        shapes = {"positions": (b, n, 2), "velocities": (b, n, 2), "landmarks": (b, num_l, 2), "step": (b,)}
        constants = self._episode_constants()
        shapes.update({k: (b, *v.shape[:-1]) for k, v in constants.items()})
        arrays = check_state_arrays(state, shapes, self._stats)
        for key, acc in self._stats.items():
            if key in state:
                arr = np.asarray(state[key])
                if arr.shape != acc.T.shape or not np.isfinite(arr).all():
                    raise ValueError(f"state[{key!r}] must be finite with shape {acc.T.shape}, got {arr.shape}")
        steps = arrays["step"]
        if (steps < 0).any() or (steps >= self.episode_length).any() or (steps != np.round(steps)).any():
            raise ValueError(f"state['step'] must be integers in [0, {self.episode_length}), got {steps}")
        self._pos[...] = arrays["positions"].transpose(1, 2, 0)
        self._vel[...] = arrays["velocities"].transpose(1, 2, 0)
        self._lm[...] = arrays["landmarks"].transpose(1, 2, 0)
        self._t[...] = steps
        for k, v in constants.items():
            v[...] = np.moveaxis(arrays[k], 0, -1)
        for k, v in self._stats.items():
            v[...] = np.asarray(state[k]).T if k in state else 0
        self._geometry()
        self._observe()
        return self._finish_obs()

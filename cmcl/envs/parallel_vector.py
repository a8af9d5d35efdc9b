"""M copies of any PettingZoo ParallelEnv behind the interface of the batched twins (cmcl/envs/batched.py).

Where it sits: `cmcl.system.make_batched_env` returns one when `env.factory` is set, so the inline loop and the
rollout worker step your environment exactly as they step the built-in twins (which stay the fast path). It steps
the M copies one after another in Python; a slow environment is what many rollout workers are for.

Shapes (B = num_envs worlds, N agents, od = max observation width, ad = max action width): obs float32[B, N, od]
and actions float32[B, N, ad] zero-padded per agent (`obs_dims`, `act_dims`, `act_mask`); actions in [-1, 1] are
mapped onto each agent's Box bounds, or, when every agent's action space is Discrete(n) (`discrete`), an agent's
first n entries (its Gumbel-softmax sample, ALGORITHM.md A17) are its action start + argmax. Episodes end as the
env ends them (every agent terminated or truncated, or no agent left) or at `episode_length` steps, each world on
its own. An agent that leaves before its world ends observes zeros and earns 0 until the world ends.
info: "final_obs" [B, N, od] (next_obs of this step), "episode_mask" bool[B] (worlds whose episode ended now),
"terminated" bool[B, N] per agent: the agent terminated in this step (its env flag, without truncation), or had
left its world before this step (an absorbing state: it earns nothing more); no bootstrapping for that agent's
critic there (`done` of eq. 5 per agent). "episode" over the M ended worlds: return float64[M, N], length
int64[M], and success / coverage float64[M]: the mean, over the agents that reported the info key named by
`success_key` / `coverage_key` during the episode, of each one's last value (an agent that left early counts with
the value it had when it left; an agent that never reported it is not counted; 0 when none did).

Observations are checked against the agent's declared Box (`check_observation`): the size at every reset and step
(a wrong-sized observation is never broadcast), and the shape, the dtype (castable to the space's, "same_kind"),
finiteness and the bounds at every reset, every step of each world's first episode and every `CHECK_EVERY`-th step
of a world after it; `ObservationError` names the agent, the step and the offending entry.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from cmcl.envs.factory import AgentSpec, EnvCrashed, EnvFactoryError, crash_text, describe, teams_of

SEED_RANGE = 2**31 - 1  # env.reset(seed=...) draws from [0, SEED_RANGE)
CHECK_EVERY = 64  # after its first episode, a world's observations get the full check at one step in this many


class ObservationError(EnvFactoryError):
    """An observation does not fit the agent's declared observation space (the message names agent and step)."""


def check_observation(value: Any, space: Any, *, full: bool) -> str | None:
    """What is wrong with `value` as an observation of the Box `space` (None: nothing). Always its size (so that
    nothing is broadcast); with `full` also its shape, dtype (castable to the space's, "same_kind"), finiteness and
    bounds. Cheap enough for a sampled step, not for every step of the hot path."""
    arr = np.asarray(value)
    size = int(np.prod(space.shape))
    if arr.size != size:
        return f"has shape {arr.shape} ({arr.size} values) but its space {space} has shape {space.shape}"
    if not full:
        return None
    if arr.shape != space.shape:
        return f"has shape {arr.shape} but its space {space} has shape {space.shape}"
    if not np.can_cast(arr.dtype, space.dtype, "same_kind"):
        return f"has dtype {arr.dtype}, which does not cast to its space's {space.dtype} ({space})"
    flat = arr.astype(np.float64).ravel()
    bad = np.flatnonzero(~np.isfinite(flat))
    if bad.size:
        return f"entry {int(bad[0])} is {flat[bad[0]]} (observations must be finite)"
    low, high = np.asarray(space.low, np.float64).ravel(), np.asarray(space.high, np.float64).ravel()
    bad = np.flatnonzero((flat < low) | (flat > high))
    if bad.size:
        k = int(bad[0])
        return f"entry {k} = {flat[k]:g} lies outside its space's bounds [{low[k]:g}, {high[k]:g}] ({space})"
    return None


class VectorParallelEnv:
    """B worlds, each one copy of the environment `make()` builds; the batched twins' public API."""

    def __init__(self, make: Callable[[], Any], num_envs: int, episode_length: int,
                 seed: int | np.random.Generator | None = None, auto_reset: bool = False,
                 team_of: Mapping[str, str] | None = None, success_key: str = "", coverage_key: str = "",
                 factory: str = "env.factory"):
        self.envs = [make() for _ in range(int(num_envs))]
        self.factory = factory  # named in the errors of the user's environment
        self.specs: list[AgentSpec] = describe(self.envs[0], team_of, factory=factory)
        self.agent_ids = [s.agent_id for s in self.specs]
        self._index = {agent: i for i, agent in enumerate(self.agent_ids)}
        self.num_envs, self.num_agents = len(self.envs), len(self.specs)
        self.episode_length, self.auto_reset = int(episode_length), bool(auto_reset)
        self.obs_dims = tuple(s.obs_size for s in self.specs)
        self.act_dims = tuple(s.act_size for s in self.specs)
        self.obs_dim, self.act_dim = max(self.obs_dims), max(self.act_dims)
        self.act_mask = np.zeros((self.num_agents, self.act_dim), np.float32)  # 1 where the agent has that action
        for i, size in enumerate(self.act_dims):
            self.act_mask[i, :size] = 1.0
        self.teams = teams_of(self.specs)
        self.discrete = self.specs[0].discrete  # all agents alike (cmcl.envs.factory.describe checks)
        self.dtype = np.dtype(np.float32)
        self.stat_keys = {"success": success_key, "coverage": coverage_key}
        self._factory = factory
        self._obs_spaces = [self.envs[0].observation_space(agent) for agent in self.agent_ids]
        self._rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        b, n = self.num_envs, self.num_agents
        self._obs = np.zeros((b, n, self.obs_dim), np.float32)
        self._t = np.zeros(b, np.int64)
        self._returns = np.zeros((b, n))
        self._over = np.zeros(b, bool)  # episode ended and not restarted (auto_reset=False)
        self._stat_last = {key: np.full((b, n), np.nan) for key, info_key in self.stat_keys.items() if info_key}
        self._world_steps = np.zeros(b, np.int64)  # steps since construction, per world (sampled obs checks)
        self._first_episode = np.ones(b, bool)  # every step of a world's first episode is checked in full
        self.reset()

    # ----- observations and actions ---------------------------------------------------------------
    def _write_obs(self, out: np.ndarray, world: int, observations: Mapping[str, Any], full: bool) -> None:
        """Zero out[world], then copy each present agent's flattened observation into its row, after checking it
        against its space (`check_observation`, in `full` or its size only); ObservationError if it does not fit."""
        out[world] = 0.0
        for i, agent in enumerate(self.agent_ids):
            if agent in observations:
                value = np.asarray(observations[agent])
                problem = check_observation(value, self._obs_spaces[i], full=full) \
                    if full or value.size != self.obs_dims[i] else None
                if problem is not None:
                    where = (f"step {int(self._t[world])} of an episode" if self._t[world] else "reset") + \
                        f" (world {world})"
                    raise ObservationError(f"{self._factory}: the observation of agent {agent!r} at {where} "
                                           f"{problem}")
                out[world, i, : self.obs_dims[i]] = value.ravel()

    def _record_stats(self, world: int, infos: Mapping[str, Any]) -> None:
        """Keep each reporting agent's latest success / coverage info value (its final state if it leaves)."""
        for key, last in self._stat_last.items():
            info_key = self.stat_keys[key]
            for agent, info in infos.items():
                if agent in self._index and isinstance(info, Mapping) and info_key in info:
                    last[world, self._index[agent]] = float(info[info_key])

    def _env_action(self, i: int, action: np.ndarray) -> np.ndarray | int:
        """Policy action float32[ad] of agent i -> its Box action (bounds, shape) from [-1, 1], or its Discrete
        action (int: start + argmax of its first n entries)."""
        spec = self.specs[i]
        if spec.discrete_start is not None:
            return spec.discrete_start + int(np.argmax(action[: spec.act_size]))
        a = np.clip(action[: spec.act_size], -1.0, 1.0)
        return (spec.act_low + (a + 1.0) * 0.5 * (spec.act_high - spec.act_low)).reshape(spec.act_shape)

    def _reset_world(self, world: int) -> None:
        try:
            observations, infos = self.envs[world].reset(seed=int(self._rng.integers(SEED_RANGE)))
        except EnvFactoryError:
            raise
        except Exception as err:  # noqa: BLE001 - the user's code: whatever it raises ends the run, kept
            raise EnvCrashed(crash_text(self.factory, f"reset of world {world}", err)) from err
        self._t[world], self._returns[world], self._over[world] = 0, 0.0, False
        self._write_obs(self._obs, world, observations, full=True)
        for last in self._stat_last.values():
            last[world] = np.nan
        self._record_stats(world, infos)

    # ----- public API ------------------------------------------------------------------------------
    def reset(self, seed: int | np.random.Generator | None = None) -> np.ndarray:
        """Start new episodes in all B worlds; returns obs float32[B, N, od]. A seed re-seeds the generator."""
        if seed is not None:
            self._rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        for world in range(self.num_envs):
            self._reset_world(world)
        return self._obs.copy()

    def observe(self) -> np.ndarray:
        return self._obs.copy()

    def step(self, actions: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Advance every running world one step with actions float[B, N, ad]; see the module docstring."""
        a = np.asarray(actions, np.float32)
        want = (self.num_envs, self.num_agents, self.act_dim)
        if a.shape != want:
            raise ValueError(f"actions must have shape (num_envs, num_agents, act_dim) = {want}, got {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError("actions must be finite")
        rewards = np.zeros((self.num_envs, self.num_agents), np.float32)
        ended, terminated = np.zeros(self.num_envs, bool), np.zeros((self.num_envs, self.num_agents), bool)
        final = np.zeros_like(self._obs)
        stats: dict[str, list[float]] = {key: [] for key in self._stat_last}
        for world, env in enumerate(self.envs):
            if self._over[world]:
                continue
            live = list(env.agents)
            try:
                observations, rew, term, trunc, infos = env.step(
                    {agent: self._env_action(self._index[agent], a[world, self._index[agent]]) for agent in live})
            except Exception as err:  # noqa: BLE001 - the user's code: whatever it raises ends the run, kept
                raise EnvCrashed(crash_text(self.factory, f"step {self._t[world] + 1} of world {world} (agents "
                                            f"{', '.join(live)})", err)) from err
            self._t[world] += 1
            self._world_steps[world] += 1
            full = self._first_episode[world] or self._world_steps[world] % CHECK_EVERY == 0
            self._write_obs(final, world, observations, full=bool(full))
            self._record_stats(world, infos)
            for agent, r in rew.items():
                rewards[world, self._index[agent]] = r
            terminated[world] = [agent not in live or (term.get(agent, False) and not trunc.get(agent, False))
                                 for agent in self.agent_ids]
            finished = all(term.get(x, False) or trunc.get(x, False) for x in live)
            if finished or not env.agents or self._t[world] >= self.episode_length:
                ended[world] = True
                self._first_episode[world] = False
                for key, values in stats.items():
                    found = self._stat_last[key][world]
                    found = found[~np.isnan(found)]
                    values.append(float(found.mean()) if found.size else 0.0)
        self._returns += rewards
        idx = np.flatnonzero(ended)
        episode: dict[str, np.ndarray] = {"return": self._returns[idx].copy(), "length": self._t[idx].copy()}
        episode.update({key: np.asarray(values, np.float64) for key, values in stats.items()})
        running = ~self._over
        self._obs[running] = final[running]
        info = {"final_obs": final, "episode_mask": ended, "terminated": terminated, "episode": episode}
        for world in idx:
            if self.auto_reset:
                self._reset_world(int(world))
            else:
                self._over[world] = True
        return self._obs.copy(), rewards, ended, info

    def set_world_settings(self, name: str, idx: np.ndarray, values: np.ndarray) -> None:
        """World setting `name` = values float64[M] for the worlds idx int64[M] from each one's next reset on, through
        each copy's own `set_setting` (the sparse tasks', cmcl.envs.world_settings)."""
        for world, value in zip(np.asarray(idx).tolist(), np.asarray(values).tolist(), strict=True):
            self.envs[world].set_setting(name, value)

    # ----- state -----------------------------------------------------------------------------------
    def get_state(self) -> dict[str, np.ndarray]:
        """An arbitrary environment cannot be saved: {} (a resumed run starts new episodes, see `set_state`)."""
        return {}

    def set_state(self, state: Mapping[str, Any]) -> np.ndarray:
        """Start new episodes in every world (there is no world state to load); returns their obs [B, N, od]."""
        if state:
            raise ValueError(f"a factory environment has no state to load, got keys {sorted(state)}")
        return self.reset()

    def render(self, world: int = 0) -> Any:
        return self.envs[world].render()

    def close(self) -> None:
        for env in self.envs:
            env.close()

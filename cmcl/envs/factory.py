"""Your own environment: load `env.factory`, check its spaces, and describe its agents as the learner sees them.

Where it sits: `cmcl.system.make_batched_env` builds `cmcl.envs.parallel_vector.VectorParallelEnv` from the
`AgentSpec`s made here when `env.factory` is set. Supported: a PettingZoo `ParallelEnv` whose observation spaces
are `Box` (any shape, flattened) and whose action spaces are either all `Box` with finite bounds (any shape,
flattened) or all `Discrete` (n actions: the actor outputs n logits, Gumbel-softmax, ALGORITHM.md A17). Agents
may differ in both sizes: the learner pads every observation and action with zeros to the largest (`obs_dim`,
`act_dim`) and masks the padded action entries (`act_mask`). Anything else (MultiDiscrete, Box and Discrete agents
in one environment, ...) raises `EnvFactoryError` naming the agent and the space.
"""

from __future__ import annotations

import importlib
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

TEAM_SUFFIX = re.compile(r"_\d+$")  # adversary_0 -> team "adversary"


class EnvFactoryError(ValueError):
    """`env.factory` cannot be loaded, or the environment it builds is not supported."""


class EnvCrashed(EnvFactoryError):
    """The user's environment raised while it was reset or stepped during training: the runners
    checkpoint, write the summary and exit with this one line; `resume` goes on from the checkpoint."""


def crash_text(factory: str, what: str, err: BaseException) -> str:
    """'<factory>: <what> raised KeyError: 'x' (at env.py line 12, in step)': the error and the user's line it
    came from (the innermost frame of its traceback); factory is its description ("env.factory 'pkg:fn'")."""
    frame, tb = None, err.__traceback__
    while tb is not None:
        frame, tb = tb, tb.tb_next
    where = "" if frame is None else \
        f" (at {frame.tb_frame.f_code.co_filename.rsplit('/', 1)[-1]} line {frame.tb_lineno}, in " \
        f"{frame.tb_frame.f_code.co_name})"
    return f"{factory}: {what} raised {type(err).__name__}: {err}{where}"


@dataclass(frozen=True)
class AgentSpec:
    """One agent as the learner sees it: its id, team, flat observation width and flat action bounds.

    act_low / act_high: float32[act_size], the env's Box bounds; the policy's tanh output a in [-1, 1] maps to
    low + (a + 1) / 2 (high - low). act_shape: the env's action shape (the flat action is reshaped to it).
    discrete_start: None for a Box; for Discrete(n, start) its `start`, the policy's output being n probabilities
    (act_low / act_high then zeros / ones of size n, act_shape ()) and the env's action start + their argmax.
    """

    agent_id: str
    team: str
    obs_size: int
    act_low: np.ndarray
    act_high: np.ndarray
    act_shape: tuple[int, ...]
    discrete_start: int | None = None

    @property
    def discrete(self) -> bool:
        return self.discrete_start is not None

    @property
    def act_size(self) -> int:
        return int(self.act_low.size)


def load_factory(path: str, kwargs: Mapping[str, Any] | None = None) -> Callable[[], Any]:
    """'package.module:callable' -> a function of no arguments that builds one environment (`callable(**kwargs)`);
    EnvFactoryError when it returns an AEC environment (naming the module's `parallel_env` when it has one)."""
    module_name, _, attr = path.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as err:
        raise EnvFactoryError(f"env.factory {path!r}: cannot import module {module_name!r} ({err})") from None
    target: Any = module
    for part in attr.split("."):
        if not hasattr(target, part):
            raise EnvFactoryError(f"env.factory {path!r}: module {module_name!r} has no attribute {attr!r}")
        target = getattr(target, part)
    if not callable(target):
        raise EnvFactoryError(f"env.factory {path!r}: {attr!r} is not callable")
    args = dict(kwargs or {})

    def build() -> Any:
        env = target(**args)
        if is_aec(env):  # it would pass `describe` (same attribute names) and fail at reset() with a bare TypeError
            hint = (f"; use {module_name + ':parallel_env'!r}" if hasattr(module, "parallel_env") else
                    "; wrap it with pettingzoo.utils.conversions.aec_to_parallel")
            raise EnvFactoryError(f"env.factory {path!r} returned an AEC environment ({type(env).__name__}), which "
                                  f"steps one agent at a time; cmcl needs a PettingZoo ParallelEnv{hint}")
        return env

    return build


def is_aec(env: Any) -> bool:
    """True for a PettingZoo AECEnv (or its wrappers): one agent acts per `step`, `reset` returns None."""
    from pettingzoo.utils.env import AECEnv

    return isinstance(env, AECEnv) or (hasattr(env, "agent_selection") and hasattr(env, "last"))


def describe(env: Any, team_of: Mapping[str, str] | None = None, *, factory: str = "env.factory") -> list[AgentSpec]:
    """The AgentSpec of every agent of `env` (in `possible_agents` order), or EnvFactoryError naming what is wrong."""
    from gymnasium import spaces

    for name in ("possible_agents", "observation_space", "action_space", "reset", "step"):
        if not hasattr(env, name):
            raise EnvFactoryError(f"{factory} returned {type(env).__name__}, not a PettingZoo ParallelEnv "
                                  f"(it has no {name!r})")
    agents = list(env.possible_agents)
    if not agents:
        raise EnvFactoryError(f"{factory}: the environment has no agents (possible_agents is empty)")
    team_of = dict(team_of or {})
    unknown = sorted(set(team_of) - set(agents))
    if unknown:
        raise EnvFactoryError(f"env.team_of names {unknown[0]!r}, not an agent of the environment: {agents}")
    specs = []
    for agent in agents:
        obs_space, act_space = env.observation_space(agent), env.action_space(agent)
        if not isinstance(obs_space, spaces.Box):
            raise EnvFactoryError(f"{factory}: agent {agent!r} has observation space {obs_space}; only Box "
                                  "observation spaces are supported")
        low, high, start = _action_bounds(act_space, agent, factory)
        if int(np.prod(obs_space.shape)) < 1 or low.size < 1:
            raise EnvFactoryError(f"{factory}: agent {agent!r} has an empty space ({obs_space}, {act_space})")
        team = team_of.get(agent, TEAM_SUFFIX.sub("", agent))
        specs.append(AgentSpec(agent_id=agent, team=team, obs_size=int(np.prod(obs_space.shape)), act_low=low,
                               act_high=high, act_shape=tuple(act_space.shape), discrete_start=start))
        if specs[-1].discrete != specs[0].discrete:
            raise EnvFactoryError(f"{factory}: agent {agent!r} has action space {act_space} but agent "
                                  f"{specs[0].agent_id!r} has {env.action_space(specs[0].agent_id)}; Box and "
                                  "Discrete action spaces in one environment are not supported")
    return specs


def _action_bounds(act_space: Any, agent: str, factory: str) -> tuple[np.ndarray, np.ndarray, int | None]:
    """(low, high, discrete_start) of a Box (its flat bounds, None) or a Discrete(n, start) (zeros(n), ones(n),
    start); EnvFactoryError naming the agent and the space for any other space."""
    from gymnasium import spaces

    if isinstance(act_space, spaces.Discrete):
        n = int(act_space.n)
        return np.zeros(n, np.float32), np.ones(n, np.float32), int(act_space.start)
    if not isinstance(act_space, spaces.Box):
        raise EnvFactoryError(f"{factory}: agent {agent!r} has action space {act_space}; only Box and Discrete "
                              "action spaces are supported")
    low = np.asarray(act_space.low, np.float32).ravel()
    high = np.asarray(act_space.high, np.float32).ravel()
    if not (np.isfinite(low).all() and np.isfinite(high).all() and (high > low).all()):
        raise EnvFactoryError(f"{factory}: agent {agent!r} has action space {act_space}; its bounds must be "
                              "finite with high > low")
    return low, high, None


LENGTH_ATTRIBUTES = ("max_cycles", "max_steps", "max_episode_steps")  # where PettingZoo / Gymnasium envs keep theirs
LENGTH_HOLDERS = ("aec_env", "unwrapped", "env", "single_agent_env")  # the wrapped envs searched, one level each


def declared_episode_length(env: Any) -> tuple[int, str] | None:
    """The episode length `env` declares itself, in steps, and where it was found ('max_cycles', 'spec.max_episode_
    steps', ...): the first positive integer among LENGTH_ATTRIBUTES and `spec.max_episode_steps` of `env` and of the
    envs it wraps (LENGTH_HOLDERS: a parallel wrapper's AEC env, `unwrapped`, a raw env's base env, MaMuJoCo's
    single-agent env), searched breadth first; None when it declares none."""
    seen, queue = set(), [env]
    while queue:
        candidate = queue.pop(0)
        if candidate is None or id(candidate) in seen:
            continue
        seen.add(id(candidate))
        found = [(_attribute(candidate, name), name) for name in LENGTH_ATTRIBUTES]
        found.append((_attribute(_attribute(candidate, "spec"), "max_episode_steps"), "spec.max_episode_steps"))
        for value, name in found:
            if isinstance(value, int) and not isinstance(value, bool) and value > 0:
                return value, name
        queue.extend(_attribute(candidate, holder) for holder in LENGTH_HOLDERS)
    return None


def _attribute(obj: Any, name: str) -> Any:
    """getattr(obj, name, None), also None when a property of the user's env raises."""
    try:
        return getattr(obj, name, None)
    except Exception:  # noqa: BLE001 - the user's code: a raising property declares nothing
        return None


def teams_of(specs: list[AgentSpec]) -> dict[str, list[int]]:
    """Team name -> agent indices, teams in order of their first agent."""
    teams: dict[str, list[int]] = {}
    for i, spec in enumerate(specs):
        teams.setdefault(spec.team, []).append(i)
    return teams

"""What a training run checks once, in the command's own process, before it makes its run directory or starts Ray:
the environment builds, resets and steps; the config's teams are the environment's (a user's env.factory with team
names of its own and no [teams] table gets the default team settings for each); the worlds and the replay buffer fit
in this machine's memory.

Where it sits: `cmcl.run.flags.open_run` calls `preflight` for both runners, new runs and resumes; each failure is a
ConfigError naming the key and the value, which the command prints as one line and exits 2 with (on the service,
once, instead of one traceback per actor). `evaluate` calls `check_worlds_fit` for its --episodes. Imports numpy and
the env package only (no torch, no Ray).
"""

from __future__ import annotations

import dataclasses
import errno
import socket
import sys
import tracemalloc
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from cmcl.config import Config, ConfigError, TeamConfig

CGROUP_MEMORY = Path("/sys/fs/cgroup")


def preflight(config: Config, *, teams_given: bool = True, length_given: bool = True, worker_processes: int = 1,
              check_memory: bool = True, notice: Callable[[str], None] = print) -> Config:
    """Build one world of `config`'s environment (an env.factory one also reset and stepped once), match the teams
    and check the memory; returns `config`, with the env's own teams when `teams_given` is false (no [teams] table
    anywhere) and the factory env's teams differ from the default one ("agent"), said by `notice` in one line, and,
    for an env.factory, the env's own episode length when `length_given` is false (env.episode_length set nowhere;
    `with_episode_length`). worker_processes: how many processes each step env.num_envs worlds (the service's
    rollout workers). Raises ConfigError (one line, naming the key and the value)."""
    from cmcl.system import agent_layout

    env = built_env(config)
    try:
        if config.env.factory:
            config = with_episode_length(config, env, length_given, notice)
            flattened = flattened_observations(env)
            if flattened:
                notice(f"note: {flattened}")
        if config.env.factory and not teams_given and set(env.teams) != set(config.teams):
            members = "; ".join(f"{team}: {', '.join(env.agent_ids[i] for i in idx)}"
                                for team, idx in env.teams.items())
            config = dataclasses.replace(config, teams={team: TeamConfig() for team in env.teams})
            notice(f"teams: no [teams] table, so each team of env.factory {config.env.factory!r} gets the default "
                   f"team settings (algorithm {TeamConfig().algorithm!r}): {members}")
        rounded = rounded_episodes(config)
        if rounded:
            notice(f"note: {rounded}")
        layout = agent_layout(config, env)
        if check_memory:
            check_memory_fits(config, layout, worker_processes)
    finally:
        _close(env)
    return config


def with_episode_length(config: Config, env: Any, given: bool, notice: Callable[[str], None]) -> Config:
    """`config` with the episode length an env.factory run uses, said by `notice` in one line either way: the
    env.episode_length set (`given`); else the env's own (`cmcl.envs.factory.declared_episode_length` of `env`'s first
    world: max_cycles, max_steps, spec.max_episode_steps); else env.episode_length's default, the built-in tasks'
    30 steps, at which longer episodes are cut."""
    from cmcl.envs.factory import declared_episode_length

    declared = declared_episode_length(env.envs[0])
    length, factory = config.env.episode_length, config.env.factory
    if given:
        own = f"; the env's own {declared[1]} is {declared[0]}" if declared and declared[0] != length else ""
        notice(f"episode length: {length} steps, as env.episode_length sets it{own}")
        return config
    if declared is None:
        notice(f"episode length: {length} steps, env.episode_length's default: env.factory {factory!r} declares none "
               "(no max_cycles, max_steps or spec.max_episode_steps), so longer episodes are cut at "
               f"{length} steps; set env.episode_length to change it")
        return config
    notice(f"episode length: {declared[0]} steps, the env's own {declared[1]} (env.episode_length sets another)")
    return dataclasses.replace(config, env=dataclasses.replace(config.env, episode_length=declared[0]))


def rounded_episodes(config: Config) -> str:
    """'' when run.episodes is a multiple of env.num_envs; else what the run plays instead: both runners play the
    env.num_envs worlds' episodes together (a rollout chunk is one episode of each world), so a built-in task's run
    ends at the next multiple, an env.factory's (episodes of their own lengths) up to env.num_envs − 1 past it."""
    episodes, worlds = config.run.episodes, config.env.num_envs
    if episodes % worlds == 0:
        return ""
    played = -(-episodes // worlds) * worlds
    ends = (f"it ends after {played} episodes" if not config.env.factory else
            f"it ends up to {worlds - 1} episodes past it")
    return (f"run.episodes = {episodes} is not a multiple of env.num_envs = {worlds}, the worlds played at once: "
            f"{ends} (set run.episodes = {played}, or env.num_envs, to make it exact)")


def flattened_observations(env: Any) -> str:
    """'' when every agent of the env.factory `env` (a VectorParallelEnv) observes a vector; else one line saying
    that observations of rank > 1 (images, grids) are flattened for the MLP networks, with the first such agent's
    shape and width and how many agents have one."""
    shapes = {agent: tuple(env.envs[0].observation_space(agent).shape) for agent in env.agent_ids}
    ranked = [agent for agent, shape in shapes.items() if len(shape) > 1]
    if not ranked:
        return ""
    first = ranked[0]
    more = len(ranked) - 1
    others = f" (and {more} more agent{'s' if more > 1 else ''} alike)" if more else ""
    return (f"the observations of agent {first!r}{others} have shape {shapes[first]}: they are flattened to "
            f"{int(np.prod(shapes[first])):,} inputs of the MLP networks, which see no image or grid structure "
            "(no convolution; docs/OWN_ENVIRONMENT.md)")


def built_env(config: Config) -> Any:
    """One world of `config`'s environment, built (and, for an env.factory, reset and stepped once with the middle
    action); any error of the user's code becomes a ConfigError naming env.factory and what raised."""
    from cmcl.envs.factory import EnvCrashed, EnvFactoryError
    from cmcl.system import make_batched_env

    factory = config.env.factory
    if not factory:
        return make_batched_env(config, num_envs=1, seed=0)
    # the checks are of the factory's own env (its spaces, max_cycles, teams), whose twin (env.twin) steps the same
    config = dataclasses.replace(config, env=dataclasses.replace(config.env, twin=False))
    try:
        env = make_batched_env(config, num_envs=1, seed=0)
    except EnvFactoryError as err:
        raise ConfigError(str(err)) from None
    except Exception as err:  # noqa: BLE001 - the user's code: anything it raises is reported, in one line
        raise ConfigError(f"env.factory {factory!r} (with env.factory_kwargs {config.env.factory_kwargs}): building "
                          f"and resetting the environment raised {_described(err)}") from None
    try:
        env.step(np.zeros((1, env.num_agents, env.act_dim), np.float32))
    except Exception as err:  # noqa: BLE001
        err = err.__cause__ if isinstance(err, EnvCrashed) and err.__cause__ is not None else err  # the user's own
        _close(env)
        raise ConfigError(f"env.factory {factory!r}: its first step (every agent's middle action) raised "
                          f"{_described(err)}") from None
    return env


def _described(err: BaseException) -> str:
    """'KeyError: 'map_file' (in reach.py line 12, Reach.__init__)': the error and where the user's code raised it."""
    frame = None
    tb = err.__traceback__
    while tb is not None:
        frame, tb = tb, tb.tb_next
    where = ""
    if frame is not None:
        code = frame.tb_frame.f_code
        where = f" (at {Path(code.co_filename).name} line {frame.tb_lineno}, in {code.co_name})"
    return f"{type(err).__name__}: {err}{where}"


def _close(env: Any) -> None:
    close = getattr(env, "close", None)
    if close is not None:
        try:
            close()
        except Exception:  # noqa: BLE001, S110 - a failing close of a probe env changes nothing
            pass


def metrics_port_checked(config: Config, port_given: bool) -> Config:
    """`config` once service.metrics_port is free: a port the user chose (`port_given`) is refused when in use
    (ConfigError naming it); the default one (9100, also node_exporter's) is then replaced by 0 (a free port, which the
    launcher's `metrics:` line names), said in a note on stderr."""
    s = config.service
    if not port_given and port_in_use(s.metrics_host, s.metrics_port, "service.metrics_port"):
        print(f"note: service.metrics_port = {s.metrics_port} is in use on {s.metrics_host}; the metrics are served on "
              "a free port instead (the `metrics:` line names it; --metrics-port chooses one)", file=sys.stderr)
        return dataclasses.replace(config, service=dataclasses.replace(s, metrics_port=0))
    check_port_free(s.metrics_host, s.metrics_port, "service.metrics_port")
    return config


def check_port_free(host: str, port: int, key: str) -> None:
    """ConfigError naming `key` when TCP `port` on `host` cannot be bound now (in use, or a host not of this
    machine); port 0 (any free port) always passes."""
    if port_in_use(host, port, key):
        raise ConfigError(f"{key} = {port} is in use on {host}: pass --metrics-port 0 for a free port, or another "
                          "port")


def port_in_use(host: str, port: int, key: str) -> bool:
    """Whether TCP `port` on `host` is taken now (port 0, any free port: never); ConfigError naming `key` when `host`
    is no address of this machine."""
    if port == 0:
        return False
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the HTTP server binds it
        try:
            probe.bind((host, port))
        except OSError as err:
            if err.errno == errno.EADDRINUSE:
                return True
            raise ConfigError(f"service.metrics_host = {host!r} cannot serve {key} = {port} here "
                              f"({err.strerror or err}): pass --metrics-host with an address of this machine") from None
    return False


# ----- memory ---------------------------------------------------------------------------------------------------
def available_memory() -> int | None:
    """Bytes this process may still allocate: /proc/meminfo's MemAvailable, lowered to the cgroup's limit minus its
    use when one is set; None when neither can be read (not Linux)."""
    found = []
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                found.append(int(line.split()[1]) * 1024)
    except (OSError, ValueError, IndexError):
        pass
    try:
        limit = (CGROUP_MEMORY / "memory.max").read_text().strip()
        if limit != "max":
            found.append(int(limit) - int((CGROUP_MEMORY / "memory.current").read_text()))
    except (OSError, ValueError):
        pass
    return min(found) if found else None


def traced_slope(build: Callable[[int], Any], small: int, large: int) -> float:
    """Bytes per unit of `build(n)` (worlds, rows): the difference of the peak memory traced while building `large`
    and `small` units, over `large - small` (numpy's allocations are traced)."""
    build(small)  # imports and caches first: they are not part of a unit's cost
    peaks = []
    for n in (small, large):
        tracemalloc.start()
        try:
            built = build(n)
            peaks.append(tracemalloc.get_traced_memory()[1])
            del built
        finally:
            tracemalloc.stop()
    return max(0.0, (peaks[1] - peaks[0]) / (large - small))


def bytes_per_world(config: Config) -> float:
    """Memory one world of `config`'s environment takes once reset (its state, observations, returns)."""
    from cmcl.system import make_batched_env

    def build(n: int) -> Any:
        env = make_batched_env(config, num_envs=n, seed=0)
        env.reset()
        return env

    return traced_slope(build, 1, 3) if config.env.factory else traced_slope(build, 2, 66)  # a user env may be slow


PROBE_BYTES = 64 * 2**20  # the most the measuring of a replay row allocates (bytes): wide observations get few rows


def storage_bytes_per_row(layout: Any) -> int:
    """Bytes one row of the replay's ring storage takes by its layout (cmcl.replay.storage), N = layout.num_agents:
    obs and next_obs float32[N, obs_dim] each (both copies), act float32[N, act_dim], reward, done and the score
    columns float32[N], their scored flags and `present` bool[N], five int64 counters; computed, never allocated."""
    from cmcl.replay.storage import SCORE_COLUMNS

    n = layout.num_agents
    floats = n * (2 * layout.obs_dim + layout.act_dim + 2 + len(SCORE_COLUMNS))
    return 4 * floats + n * (len(SCORE_COLUMNS) + 1) + 8 * 5


def bytes_per_row(config: Config, layout: Any) -> float:
    """Memory one row of `config`'s replay buffer takes (storage, priorities, indices): measured on small buffers
    whose storage stays within PROBE_BYTES, and never below `storage_bytes_per_row`."""
    from cmcl.system import build_replay

    computed = storage_bytes_per_row(layout)
    large = int(min(4608, max(16, PROBE_BYTES // computed)))

    def build(capacity: int) -> Any:
        maddpg = dataclasses.replace(config.maddpg, warmup=min(config.maddpg.warmup, capacity),
                                     batch_size=min(config.maddpg.batch_size, capacity))
        small = dataclasses.replace(config, replay=dataclasses.replace(config.replay, capacity=capacity),
                                    maddpg=maddpg)
        return build_replay(small, layout)

    return max(float(computed), traced_slope(build, max(8, large // 9), large))


def size(amount: float) -> str:
    """1536 -> '1.5 KiB'."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if amount < 1024 or unit == "TiB":
            return f"{amount:.0f} {unit}" if unit == "B" else f"{amount:.1f} {unit}"
        amount /= 1024
    raise AssertionError("unreachable")


def refuse_unless_fits(needs: dict[str, tuple[Any, float, str]], available: int | None) -> None:
    """ConfigError when the memory `needs` ({key: (value, bytes, what)}) sum to more than `available`, naming the
    key that needs the most and its value."""
    total = sum(need for _, need, _ in needs.values())
    if available is None or total <= available:
        return
    key, (value, need, what) = max(needs.items(), key=lambda item: item[1][1])
    in_all = f"; the run needs {size(total)} in all" if len(needs) > 1 else ""
    raise ConfigError(f"{key} = {value} needs about {size(need)} of memory for {what}{in_all}, more than the "
                      f"{size(available)} this machine has available; lower {key}")


def check_memory_fits(config: Config, layout: Any, worker_processes: int = 1) -> None:
    """ConfigError when env.num_envs worlds (in each of `worker_processes`) and replay.capacity rows do not fit in
    the memory available now (estimated from small instances, before anything large is allocated)."""
    available = available_memory()
    if available is None:
        return
    computed = storage_bytes_per_row(layout)  # before anything is measured: a probe of a huge row would not fit
    refuse_unless_fits({"replay.capacity": (config.replay.capacity, computed * config.replay.capacity,
                                            f"the replay buffer ({replay_row_text(layout, computed)})")}, available)
    per_world, per_row = bytes_per_world(config), bytes_per_row(config, layout)
    worlds = config.env.num_envs * worker_processes
    refuse_unless_fits({
        "env.num_envs": (config.env.num_envs, per_world * worlds,
                         f"its {worlds} worlds ({size(per_world)} each)"),
        "replay.capacity": (config.replay.capacity, per_row * config.replay.capacity,
                            f"the replay buffer ({replay_row_text(layout, per_row)})"),
    }, available)


def replay_row_text(layout: Any, row_bytes: float) -> str:
    """'3.1 MiB per row: 2 agents × 403,200-wide observations, stored twice (obs, next_obs), float32'."""
    return (f"{size(row_bytes)} per row: {layout.num_agents} agents × {layout.obs_dim:,}-wide observations, stored "
            "twice (obs, next_obs), float32")


def check_worlds_fit(config: Config, worlds: int, flag: str) -> None:
    """ConfigError naming `flag` when `worlds` worlds of `config`'s environment do not fit in the memory available
    (evaluate's --episodes: one world per episode)."""
    available = available_memory()
    if available is None:
        return
    per_world = bytes_per_world(config)
    refuse_unless_fits({flag: (worlds, per_world * worlds, f"{worlds} worlds ({size(per_world)} each)")}, available)


__all__ = ["available_memory", "check_memory_fits", "check_port_free", "check_worlds_fit", "preflight"]

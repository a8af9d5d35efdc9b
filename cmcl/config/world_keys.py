"""The built-in worlds' keys that a run with env.factory does not read, and the check that a run sets none of them.

With env.factory the user's PettingZoo environment decides its agents, landmarks, radii and rewards: the flat [env]
keys of the built-in tasks (every key of cmcl.config.env.WORLD_KEYS: env.num_agents, env.cover_radius, env.tag_...,
and env.task) describe the batched twins only. Before (found by hand 2026-12-06), `--set env.num_agents=3` with
env.factory trained the factory's environment as it was and said nothing. The rule follows cmcl.config.runners': a
key given explicitly, with a value other than its default, is
  * refused when it comes from `--set` (one line naming the key, the factory and the value; the environment's own
    settings go in env.factory_kwargs);
  * named in a one-line note on stderr when it comes from the config file (a file may describe the built-in world
    too).

Where it sits: `cmcl.run.flags.open_run` (a new run: the file's keys and the overrides) and `resumed_config` (a
resume: its overrides) call `check_world_keys`, beside `check_runner_keys`, before the run directory changes.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from cmcl.config.checks import ConfigError
from cmcl.config.env import WORLD_KEYS, EnvConfig
from cmcl.config.experiment import Config
from cmcl.config.toml_io import parse_override


def _world_value(env: EnvConfig, name: str) -> Any:
    """The value of flat [env] key `name` (a WORLD_KEYS key or "task") in `env`."""
    if name == "task":
        return env.task
    where = WORLD_KEYS[name]
    return getattr(getattr(env, where.task), where.name)


def note_on_stderr(line: str) -> None:
    print(line, file=sys.stderr)


def check_world_keys(config: Config, file_data: Mapping[str, Any] | None = None, overrides: Iterable[str] = (),
                     note: Callable[[str], None] = note_on_stderr) -> None:
    """Apply the module's rule to the resolved `config`: `file_data` the config file's tables (as parsed),
    `overrides` the `--set` strings. Raises ConfigError (one line) for a key refused; calls `note` with one line
    naming the file's world keys that are not read."""
    factory = config.env.factory
    if not factory:
        return
    given = [(parse_override(text)[0], "set") for text in overrides]
    env_table = (file_data or {}).get("env", {})
    given += [(["env", name], "file") for name in (env_table if isinstance(env_table, Mapping) else {})]
    defaults, unread = Config().env, []
    for path, source in given:
        if len(path) != 2 or path[0] != "env" or (path[1] not in WORLD_KEYS and path[1] != "task"):
            continue
        key, value = ".".join(path), _world_value(config.env, path[1])
        if value == _world_value(defaults, path[1]):
            continue
        if source == "set":
            raise ConfigError(f"{key} describes the built-in worlds, which env.factory {factory!r} replaces: the "
                              "environment decides it (pass its own settings in env.factory_kwargs), got "
                              f"{value!r}")
        unread.append(f"{key} = {value!r}")
    if unread:
        note(f"note: with env.factory {factory!r} the config file's {'; '.join(unread)} describe the built-in "
             "worlds and are not read")

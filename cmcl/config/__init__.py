"""Typed, validated run configuration: one frozen dataclass per component, loaded from TOML.

Where it sits: every command (`python -m cmcl train | resume | evaluate` and its aliases) builds a `Config` with
`load_config(path, overrides)` and hands each component its section. Defaults are the paper's Table 1 values
and the resolutions of ALGORITHM.md §5 (each [R] choice is an option here with that default).

Layout: the section dataclasses, each field's range check in its own metadata: `learning` ([maddpg], [replay],
[curriculum], [teachers], [icm]), `teams` ([teams.<team>] and [teams.<team>.priority]), `run_and_service` ([run],
[service]), `env` (the [env] section and the tasks: the world parameters are cmcl.envs.params' SpreadParams /
TagParams, under their flat TOML keys); `checks` (`ConfigError` and the range checks), `experiment` (`Config`, its
derived quantities, `preset`), `toml_io` (mapping / TOML loading, `--set` overrides, type coercion, `dump_toml`),
`reference` (every key's
meaning, unit, default and range from the fields' metadata: `python -m cmcl config`, docs/CONFIG.md).
Import every name from `cmcl.config`; the submodules are an implementation detail.

Errors: any unknown key, wrong type or out-of-range value raises `ConfigError` naming the full key
(e.g. ``maddpg.gamma``) and the offending value.
"""

from cmcl.config.checks import ConfigError
from cmcl.config.env import TASK_TEAMS, TASKS, EnvConfig, TaskCurriculumConfig
from cmcl.config.experiment import Config, preset
from cmcl.config.learning import CurriculumConfig, ICMConfig, MADDPGConfig, ReplayConfig, TeacherConfig
from cmcl.config.run_and_service import RunConfig, ServiceConfig
from cmcl.config.teams import DEFAULT_ALPHA, PriorityConfig, TeamConfig
from cmcl.config.toml_io import (
    apply_overrides,
    config_from_dict,
    dump_toml,
    load_config,
    load_data,
    load_stored_config,
    parse_override,
)
from cmcl.replay.registry import ALGORITHMS

__all__ = ["ALGORITHMS", "DEFAULT_ALPHA", "TASKS", "TASK_TEAMS", "ConfigError",
           "CurriculumConfig", "ICMConfig", "MADDPGConfig", "PriorityConfig", "ReplayConfig", "RunConfig",
           "ServiceConfig", "TeacherConfig", "TeamConfig",
           "Config", "EnvConfig", "TaskCurriculumConfig", "apply_overrides", "config_from_dict", "dump_toml",
           "load_config", "load_data", "load_stored_config", "parse_override", "preset"]

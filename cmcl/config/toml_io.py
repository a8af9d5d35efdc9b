"""TOML in and out: build a validated `Config` from a nested mapping or a TOML file with `--set` overrides, and
render one back as TOML.

Errors: any unknown key or value of the wrong type raises `ConfigError` naming the full key and the value
(range checks are the sections' own, cmcl.config.learning, cmcl.config.teams, cmcl.config.run_and_service and
cmcl.config.env, and the world parameters' own, cmcl.envs.params).
"""

from __future__ import annotations

import dataclasses
import difflib
import re
import tomllib
import types
import typing
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, Literal

from cmcl.config.checks import ConfigError, _require
from cmcl.config.env import TASK_TEAMS, TASKS, WORLD_KEYS, EnvConfig, WorldKey
from cmcl.config.experiment import Config
from cmcl.config.teams import PriorityConfig, TeamConfig
from cmcl.replay.registry import REGISTRY, register_file
from cmcl.replay.snapshot import older_run

_SECTIONS = {f.name: f for f in dataclasses.fields(Config) if f.name != "teams"}


_TYPE_REQUIREMENTS = {bool: "must be true or false", int: "must be an integer", float: "must be a number",
                      str: "must be a string", Any: "must be a number, a string or a boolean"}


def type_requirement(hint: Any) -> str:
    """What a value of type hint `hint` must be, in the words of the ConfigError `_coerce` raises for it."""
    origin = typing.get_origin(hint)
    if origin is Literal:
        return f"must be one of {list(typing.get_args(hint))}"
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in typing.get_args(hint) if a is not type(None)]
        return type_requirement(inner[0]) + (" (or unset)" if len(inner) < len(typing.get_args(hint)) else "")
    if origin is dict:
        return "must be a table"
    if origin is tuple:
        return f"must be an array (each entry {type_requirement(typing.get_args(hint)[0])})"
    return _TYPE_REQUIREMENTS[hint]


def _coerce(key: str, value: Any, hint: Any) -> Any:
    """Check `value` against the type hint `hint` (bool, int, float, str, Literal, Optional)."""
    origin = typing.get_origin(hint)
    if origin is Literal:
        _require(value in typing.get_args(hint), key, value, type_requirement(hint))
        return value
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(hint)
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _coerce(key, value, inner[0])
    if hint is bool:
        _require(isinstance(value, bool), key, value, type_requirement(hint))
        return value
    if hint is int:
        _require(isinstance(value, int) and not isinstance(value, bool), key, value, type_requirement(hint))
        return value
    if hint is float:
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        _require(ok, key, value, type_requirement(hint))
        return float(value)
    if hint is str:
        _require(isinstance(value, str), key, value, type_requirement(hint))
        return value
    if origin is dict:  # a table of scalars, e.g. env.factory_kwargs = {continuous_actions = true}
        _require(isinstance(value, Mapping), key, value, type_requirement(hint))
        value_hint = typing.get_args(hint)[1]
        return {str(k): _coerce(f"{key}.{k}", v, value_hint) for k, v in value.items()}
    if hint is Any:
        _require(isinstance(value, bool | int | float | str), key, value, type_requirement(hint))
        return value
    if origin is tuple:  # an array of scalars, e.g. task_curriculum.stages = [0.1, 0.3, 1.0]
        _require(isinstance(value, list | tuple), key, value, type_requirement(hint))
        return tuple(_coerce(f"{key}[{i}]", v, typing.get_args(hint)[0]) for i, v in enumerate(value))
    raise ConfigError(f"{key}: unsupported field type {hint!r}")


def _build(cls: type, data: Mapping[str, Any], prefix: str, built: Mapping[str, Any] | None = None,
           flat_keys: Iterable[str] = ()) -> Any:
    """Build dataclass `cls` from `data`, rejecting unknown keys and values of the wrong type.

    built: fields already built by the caller (not keys of `data`); flat_keys: keys the caller has taken out of
    `data` (listed as known in the unknown-key error)."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{prefix} must be a table, got {data!r}")
    built = built or {}
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)} - set(built)
    unknown = sorted(set(data) - names)
    if unknown:
        known = sorted(names | set(flat_keys))
        near = difflib.get_close_matches(unknown[0], known, n=1)
        guess = f"; did you mean {prefix}.{near[0]}?" if near else ""
        raise ConfigError(f"unknown key {prefix}.{unknown[0]}{guess} (known: {known})")
    kwargs = {k: _coerce(f"{prefix}.{k}", v, hints[k]) for k, v in data.items()}
    try:
        return cls(**kwargs, **built)
    except ConfigError as err:
        # __post_init__ messages use the section name; re-prefix a team's checks with the team's path.
        msg, short = str(err), _CHECK_NAMES.get(cls)
        raise ConfigError(msg.replace(short, f"{prefix}.", 1) if short and msg.startswith(short) else msg) from None


# the name a section's own checks use in their messages, where its path in the TOML differs (a team's tables)
_CHECK_NAMES = {TeamConfig: "team.", PriorityConfig: "priority."}


def _build_team(data: Any, prefix: str) -> TeamConfig:
    """TeamConfig from one [teams.<team>] table: its [teams.<team>.priority] table and the options of its rule (the
    table's keys that are fields of the rule's `Rule.options`, cmcl.replay.rules.contract) built first; their range
    checks run in TeamConfig's."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{prefix} must be a table, got {data!r}")
    rule = REGISTRY.get(data.get("algorithm", TeamConfig.algorithm)) if isinstance(data.get("algorithm", ""), str) \
        else None
    option_names = [f.name for f in dataclasses.fields(rule.options)] if rule is not None else []
    shadowed = sorted(set(option_names) & {f.name for f in dataclasses.fields(TeamConfig)})
    if shadowed:
        raise ConfigError(f"{prefix}.{shadowed[0]}: rule {rule.name!r} declares an option of that name, which is a "
                          "key of every team's table; the rule must name its option otherwise")
    rest = {k: v for k, v in data.items() if k != "priority" and k not in option_names}
    priority = _build(PriorityConfig, data.get("priority", {}), f"{prefix}.priority")
    options = None if rule is None else _build(rule.options, {k: data[k] for k in option_names if k in data}, prefix)
    return _build(TeamConfig, rest, prefix, built={"priority": priority, "options": options},
                  flat_keys=("priority", *option_names))


def _build_env(data: Mapping[str, Any], prefix: str = "env") -> EnvConfig:
    """EnvConfig from the flat [env] table: each world key (WORLD_KEYS) sets a field of its task's params, starting
    from EnvConfig's defaults, and their own range checks run; errors name the key the user wrote."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{prefix} must be a table, got {data!r}")
    defaults = EnvConfig()
    worlds: dict[str, dict[str, Any]] = {task: {} for task in TASKS}
    for key, value in data.items():
        if key in WORLD_KEYS:
            home = WORLD_KEYS[key]
            hint = typing.get_type_hints(type(getattr(defaults, home.task)))[home.name]
            worlds[home.task][home.name] = _coerce(f"{prefix}.{key}", value, hint)
    key_of = {home: key for key, home in WORLD_KEYS.items()}
    built = {}
    for task, values in worlds.items():
        try:
            built[task] = dataclasses.replace(getattr(defaults, task), **values)
        except ValueError as err:  # the params' messages start with the field's name
            name, _, why = str(err).partition(" ")
            raise ConfigError(f"{prefix}.{key_of.get(WorldKey(task, name), name)} {why}") from None
    rest = {k: v for k, v in data.items() if k not in WORLD_KEYS}
    return _build(EnvConfig, rest, prefix, built=built, flat_keys=WORLD_KEYS)


def config_from_dict(data: Mapping[str, Any]) -> Config:
    """Build and validate a Config from a nested mapping (as parsed from TOML)."""
    unknown = sorted(set(data) - set(_SECTIONS) - {"teams"})
    if unknown:
        raise ConfigError(f"unknown section {unknown[0]!r} (known: {sorted([*_SECTIONS, 'teams'])})")
    sections = {name: _build_env(data.get(name, {})) if name == "env" else
                _build(f.default_factory, data.get(name, {}), name) for name, f in _SECTIONS.items()}
    for path in sections["replay"].rule_paths:  # rules kept in files of their own, registered before the teams
        if not Path(path).is_file():
            raise ConfigError(f"replay.rule_files: {path!r} is not a file")
        try:
            register_file(path)
        except ValueError as err:
            raise ConfigError(str(err)) from None
    teams_data = data.get("teams")
    if teams_data is None:  # a factory env without team tables: one team "agent" (agent_0, agent_1, ...)
        teams_data = {name: {} for name in default_teams(sections["env"])}
    if not isinstance(teams_data, Mapping):
        raise ConfigError(f"teams must be a table of team tables, got {teams_data!r}")
    teams = {name: _build_team(spec, f"teams.{name}") for name, spec in teams_data.items()}
    return Config(**sections, teams=teams)


def default_teams(env: EnvConfig) -> tuple[str, ...]:
    """The teams of a config without [teams] tables: its task's, or one team "agent" for an env.factory."""
    return ("agent",) if env.factory else TASK_TEAMS[env.task]



def parse_override(text: str) -> tuple[list[str], Any]:
    """Parse 'section.key=value' (value in TOML syntax; bare words are strings) into (path, value)."""
    if "=" not in text:
        raise ConfigError(f"override must look like section.key=value, got {text!r}")
    dotted, raw = text.split("=", 1)
    path = [part.strip() for part in dotted.strip().split(".")]
    if len(path) < 2 or not all(path):
        raise ConfigError(f"override key must be section.key, got {dotted!r}")
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    return path, value


def apply_overrides(data: dict[str, Any], overrides: Iterable[str]) -> dict[str, Any]:
    """Return a copy of nested `data` with each 'a.b.c=value' override set."""
    result = _deep_copy(data)
    for text in overrides:
        path, value = parse_override(text)
        node = result
        for part in path[:-1]:
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise ConfigError(f"override {text!r}: {part} is not a table")
            node = child
        node[path[-1]] = value
    return result


def _deep_copy(data: Mapping[str, Any]) -> dict[str, Any]:
    """A copy of nested `data` whose mappings are fresh dicts (leaf values shared)."""
    return {k: _deep_copy(v) if isinstance(v, Mapping) else v for k, v in data.items()}


def load_config(path: str | Path | None = None, overrides: Iterable[str] = ()) -> Config:
    """Load a TOML file (or the defaults when `path` is None) and apply `--set` overrides."""
    return config_from_dict(load_data(path, overrides))


def load_stored_config(path: str | Path, overrides: Iterable[str] = ()) -> Config:
    """A run directory's stored config.toml with the `--set` overrides. A key this version does not know, written
    by an older one (it wrote only known keys), is refused in one line naming it (`older_run`)."""
    data = load_data(path)
    try:
        return config_from_dict(apply_overrides(data, overrides))
    except ConfigError as err:
        if not str(err).startswith("unknown "):
            raise
        try:  # the stored keys alone: an unknown key there is the older version's, one of an override the user's
            config_from_dict(data)
        except ConfigError as stored:
            if str(stored) == str(err):
                raise ConfigError(older_run(f"{path}: {re.split(r'[;(]', str(err))[0].strip()}")) from None
        raise


def load_data(path: str | Path | None = None, overrides: Iterable[str] = ()) -> dict[str, Any]:
    """The nested mapping `load_config` builds its Config from: the TOML file's tables (none when `path` is None)
    with the `--set` overrides applied. ConfigError naming the file when it is missing, a directory, not UTF-8
    text or not TOML."""
    data: dict[str, Any] = {}
    if path is not None:
        path = Path(path)
        if path.is_dir():
            raise ConfigError(f"config file {str(path)!r} is a directory, not a TOML file")
        if not path.is_file():
            raise ConfigError(f"config file {str(path)!r} does not exist")
        try:
            data = tomllib.loads(path.read_bytes().decode("utf-8"))
        except UnicodeDecodeError as err:
            raise ConfigError(f"config file {str(path)!r} is not a TOML file: not UTF-8 text (byte "
                              f"{err.object[err.start]:#04x} at offset {err.start})") from None
        except tomllib.TOMLDecodeError as err:
            raise ConfigError(f"config file {str(path)!r} is not valid TOML: {err}") from None
        except OSError as err:
            raise ConfigError(f"config file {str(path)!r} cannot be read: {err.strerror}") from None
    return apply_overrides(data, overrides)


def dump_toml(config: Config) -> str:
    """Render a Config as TOML text that `load_config` reads back to an equal Config."""
    data = config.to_dict()
    lines: list[str] = []
    for section, values in data.items():
        if section == "teams":
            continue
        lines.append(f"[{section}]")
        lines.extend(f"{k} = {_toml_value(v)}" for k, v in values.items())
        lines.append("")
    for team, values in data["teams"].items():
        tables = {k: v for k, v in values.items() if isinstance(v, Mapping)}  # its [teams.<team>.priority]
        lines.append(f"[teams.{team}]")
        lines.extend(f"{k} = {_toml_value(v)}" for k, v in values.items() if k not in tables)
        lines.append("")
        for name, table in tables.items():
            lines.append(f"[teams.{team}.{name}]")
            lines.extend(f"{k} = {_toml_value(v)}" for k, v in table.items())
            lines.append("")
    return "\n".join(lines)


def _toml_value(value: Any) -> str:
    """One scalar as a TOML literal (bool, quoted string, or the number's repr)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, Mapping):  # an inline table; keys quoted (agent ids may hold any character)
        return "{" + ", ".join(f"{_toml_value(str(k))} = {_toml_value(v)}" for k, v in value.items()) + "}"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(value)


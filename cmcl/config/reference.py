"""The configuration reference: every key of a run configuration with its meaning, unit, default and allowed range.

Where it sits: read from the fields' own documentation (cmcl.field_docs.documented, in cmcl.config.learning,
cmcl.config.teams, cmcl.config.run_and_service, cmcl.config.env and cmcl.envs.params), nothing written twice: the
allowed range is a field's rule's text, the very text of the ConfigError its check raises, or else the type's
(`type_requirement`, the words of the type errors).
`python -m cmcl config [SECTION] [--markdown]` prints it; docs/CONFIG.md is its Markdown
(`python -m cmcl config --markdown > docs/CONFIG.md`; tests/test_config_reference.py fails when it is not current).
Defaults are a run's defaults (`Config()`), as TOML values.
"""

from __future__ import annotations

import dataclasses
import sys
import textwrap
import types
import typing
from dataclasses import dataclass
from typing import Any, Literal

from cmcl.config.env import TASKS, WORLD_KEYS, EnvConfig
from cmcl.config.experiment import Config
from cmcl.config.runners import IN_ONE_PROCESS, SERVICE_ONLY
from cmcl.config.teams import PriorityConfig, TeamConfig
from cmcl.config.toml_io import _toml_value, type_requirement
from cmcl.field_docs import MEANING, RULE, UNIT
from cmcl.replay.registry import REGISTRY

MARKDOWN_COMMAND = "python -m cmcl config --markdown > docs/CONFIG.md"


@dataclass(frozen=True)
class KeyDoc:
    """One key of a section: as written in TOML, its type, default (a TOML value or "unset"), unit, range, meaning."""

    key: str
    type: str
    default: str
    unit: str
    allowed: str
    meaning: str


@dataclass(frozen=True)
class SectionDoc:
    """One section: its TOML table ("maddpg", "teams.<team>"), what it configures, its keys in field order."""

    table: str
    summary: str
    keys: tuple[KeyDoc, ...]


def _type_name(hint: Any) -> str:
    """A short name of a field's type: "float", "str", "float or unset", "table"."""
    origin = typing.get_origin(hint)
    if origin is Literal:
        return "str"
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in typing.get_args(hint) if a is not type(None)]
        return _type_name(inner[0]) + " or unset"
    if origin is dict:
        return "table"
    return getattr(hint, "__name__", str(hint))


def _key_doc(owner: Any, field: dataclasses.Field, key: str, note: str = "") -> KeyDoc:
    """The KeyDoc of `field` of the dataclass instance `owner` (its value there is the default)."""
    hint = typing.get_type_hints(type(owner))[field.name]
    rule = field.metadata.get(RULE)
    value = getattr(owner, field.name)
    # the checks a value meets, in their order: its type's when that names the values (a Literal; else the type
    # column says it), then its range rule's
    allowed = [type_requirement(hint)] if rule is None or typing.get_origin(hint) is Literal else []
    allowed += [rule.why] if rule is not None else []
    return KeyDoc(key=key, type=_type_name(hint), default="unset" if value is None else _toml_value(value),
                  unit=field.metadata.get(UNIT, ""), allowed="; ".join(allowed),
                  meaning=note + field.metadata.get(MEANING, ""))


def _summary(cls: type) -> str:
    return " ".join((cls.__doc__ or "").split("\n\n")[0].split())


def _section(table: str, owner: Any) -> SectionDoc:
    """The keys of `owner`'s fields; a field holding a table of its own (a team's `priority`) is its own section. A
    key only the service runner honours (cmcl.config.runners) says so."""
    keys = []
    for f in dataclasses.fields(owner):
        if dataclasses.is_dataclass(getattr(owner, f.name)):
            continue
        doc = _key_doc(owner, f, f.name)
        if f"{table}.{f.name}" in SERVICE_ONLY:
            doc = dataclasses.replace(doc, meaning=f"{doc.meaning}. The service runner only: {IN_ONE_PROCESS}")
        keys.append(doc)
    return SectionDoc(table, _summary(type(owner)), tuple(keys))


def _rule_option_keys() -> tuple[KeyDoc, ...]:
    """The keys each registered rule adds to its team's table (its `Rule.options` fields), said to be its own."""
    keys = []
    for name, rule in REGISTRY.items():
        options = rule.options()
        keys += [_key_doc(options, f, f.name, note=f"(algorithm = '{name}' only) ")
                 for f in dataclasses.fields(options)]
    return tuple(keys)


def _env_section(env: EnvConfig) -> SectionDoc:
    """[env]: its own fields, with `spread` and `tag` written as their worlds' flat keys (WORLD_KEYS)."""
    keys = []
    for f in dataclasses.fields(env):
        if f.name not in TASKS:
            keys.append(_key_doc(env, f, f.name))
            continue
        world = getattr(env, f.name)
        world_fields = {wf.name: wf for wf in dataclasses.fields(world)}
        keys.extend(_key_doc(world, world_fields[home.name], key, note=f"({home.task}) ")
                    for key, home in WORLD_KEYS.items() if home.task == f.name)
    return SectionDoc("env", _summary(EnvConfig), tuple(keys))


def reference() -> dict[str, SectionDoc]:
    """Every section of a run configuration, in Config's order; "teams" is the table of each team, "teams.priority"
    each team's [teams.<team>.priority] table."""
    config = Config()
    sections = {}
    for f in dataclasses.fields(Config):
        if f.name == "env":
            sections["env"] = _env_section(config.env)
        elif f.name == "teams":
            team = _section("teams.<team>", TeamConfig())
            sections["teams"] = dataclasses.replace(team, keys=team.keys + _rule_option_keys())
            sections["teams.priority"] = _section("teams.<team>.priority", PriorityConfig())
        else:
            sections[f.name] = _section(f.name, getattr(config, f.name))
    return sections


def render_text(sections: list[SectionDoc]) -> str:
    """The terminal form: per key its default, then its meaning, unit, type and allowed range."""
    lines = []
    for section in sections:
        lines += [f"[{section.table}]  {section.summary}", ""]
        for k in section.keys:
            lines.append(f"  {k.key} = {k.default}")
            lines += textwrap.wrap(k.meaning, width=110, initial_indent="      meaning  ", break_on_hyphens=False,
                                   subsequent_indent=" " * 15)
            lines += [f"      unit     {k.unit or '-'}", f"      type     {k.type}", f"      allowed  {k.allowed}"]
        lines.append("")
    return "\n".join(lines)


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def _anchor(table: str) -> str:
    """A section's anchor in docs/CONFIG.md: "maddpg", "teamsteam", "teamsteam-priority"."""
    return table.replace(".<team>", "team").replace(".", "-")


def render_markdown(sections: list[SectionDoc]) -> str:
    """docs/CONFIG.md: one table per section."""
    lines = ["# Configuration reference", "",
             f"Generated by `{MARKDOWN_COMMAND}` from the fields' own documentation (`cmcl/field_docs.py`; the "
             "fields are declared in `cmcl/config/learning.py`, `cmcl/config/teams.py`, "
             "`cmcl/config/run_and_service.py`, `cmcl/config/env.py` and `cmcl/envs/params.py`); do not edit by hand. "
             "`python -m cmcl config [SECTION]` prints the same in the terminal.", "",
             "Set a key in a TOML file (`[maddpg]` then `gamma = 0.95`) or on the command line "
             "(`--set maddpg.gamma=0.95`). *Allowed* is the text of the error a value out of range gets "
             "(`maddpg.gamma must lie in [0, 1], got 2.0`). Defaults are a run's defaults (`Config()`); "
             "`configs/` holds the shipped files and `configs/paper/` the paper's presets.", "",
             "Sections: " + ", ".join(f"[`[{s.table}]`](#{_anchor(s.table)})" for s in sections),
             ""]
    for section in sections:
        anchor = _anchor(section.table)
        lines += [f'<a id="{anchor}"></a>', "", f"## `[{section.table}]`", "", section.summary, "",
                  "| key | default | unit | type | allowed | meaning |", "| --- | --- | --- | --- | --- | --- |"]
        lines += [f"| `{k.key}` | `{_cell(k.default)}` | {_cell(k.unit)} | {k.type} | {_cell(k.allowed)} | "
                  f"{_cell(k.meaning)} |" for k in section.keys]
        lines.append("")
    return "\n".join(lines)


def config_command(section: str | None, markdown: bool) -> int:
    """`python -m cmcl config [SECTION | SECTION.KEY] [--markdown]`: print the reference (of one section, or of one
    key: `maddpg.hidden`, `env.num_agents`, `teams.agent.eta`, `teams.agent.priority.alpha`); exit code."""
    sections = reference()
    if section is None or section in sections:
        chosen = list(sections.values()) if section is None else [sections[section]]
    else:
        found = _one_key(sections, section)
        if found is None:
            print(f"error: unknown section or key {section!r} (sections: {', '.join(sections)}; a key: SECTION.KEY, "
                  "e.g. maddpg.hidden or teams.agent.eta)", file=sys.stderr)
            return 2
        chosen = [found]
    print((render_markdown if markdown else render_text)(chosen), end="")
    return 0


def _one_key(sections: dict[str, SectionDoc], dotted: str) -> SectionDoc | None:
    """The section of `dotted` (SECTION.KEY; a team's keys under any team name: teams.<team>.KEY,
    teams.<team>.priority.KEY) holding that key alone (teams.<team>: the team's whole table), None when there is no
    such key."""
    parts = dotted.split(".")
    if parts[0] == "teams" and len(parts) == 2:  # teams.<team>: the team's table
        return sections["teams"]
    if parts[0] == "teams" and len(parts) >= 3:  # the team's name stands for any team
        parts = ["teams.priority", *parts[3:]] if parts[2] == "priority" and len(parts) > 3 else ["teams", *parts[2:]]
    if len(parts) != 2 or parts[0] not in sections:
        return None
    doc = sections[parts[0]]
    keys = tuple(k for k in doc.keys if k.key == parts[1])
    return dataclasses.replace(doc, keys=keys) if keys else None

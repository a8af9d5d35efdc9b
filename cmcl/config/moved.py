"""Config keys that moved: refused in what a user writes, carried over when a stored run config is read back.

Where it sits: `cmcl.config.toml_io.config_from_dict` refuses a moved key (`refuse_moved`) with one line naming its
new place, so a file or `--set` written for the old layout never trains with a value silently dropped. A run
directory written before the move stores the old keys in its config.toml; `RunDirectory.config` (resume, evaluate,
the experiments' measures) reads it through `load_stored_config`, which moves them first (`migrate_moved`), so a
stored run resumes and evaluates with exactly the settings it trained with.

The moves: the settings a team's sampler uses are one table per team, [teams.<team>.priority]
(cmcl.config.teams.PriorityConfig). A global old key applies to every team: migrated, its value goes to each
team's table; a team's own old key (teams.<team>.alpha) goes to that team's table and wins over the global one
(replay.alpha), as its precedence was.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Any

from cmcl.config.checks import ConfigError

# (section, key) of a global key that is now teams.<team>.priority.<key>, one per team
GLOBAL_MOVED: dict[tuple[str, str], str] = {
    ("teachers", "difficulty_norm"): "difficulty_norm",
    ("teachers", "difficulty_transform"): "difficulty_transform",
    ("teachers", "difficulty_error"): "difficulty_error",
    ("icm", "cp_input"): "cp_input",
    ("replay", "alpha"): "alpha",
}
# key of a team's table that is now teams.<team>.priority.<key>
TEAM_MOVED: dict[str, str] = {"alpha": "alpha", "uniform_floor": "uniform_floor"}
# (section, key) removed when the two runners became one (both schedule the same roles): what does its work now
REMOVED: dict[tuple[str, str], str] = {
    ("run", "log_every"): "both runners log a progress row every 2 s",
    ("run", "checkpoint_every"): "both runners checkpoint every service.checkpoint_every_s seconds",
    ("teachers", "rescore_rows_per_update"): "each teacher / ICM call rescores service.score_rows_per_call rows",
}


def removed_keys(data: Mapping[str, Any]) -> Iterator[tuple[str, Mapping[str, Any], str]]:
    """(dotted name, its table, its key there) of every removed key of nested `data`."""
    for (section, key) in REMOVED:
        table = data.get(section)
        if isinstance(table, Mapping) and key in table:
            yield f"{section}.{key}", table, key


def moved_keys(data: Mapping[str, Any]) -> Iterator[tuple[str | None, str, Mapping[str, Any], str, str]]:
    """The one walk over the tables of moved keys: every moved key of nested `data`, the global ones first, then each
    team's, as (team, its old dotted name, the table that holds it, its key there, its key in teams.<team>.priority);
    team None for a global key (it applies to every team). The caller may pop the key from its table."""
    for (section, key), new in GLOBAL_MOVED.items():
        table = data.get(section)
        if isinstance(table, Mapping) and key in table:
            yield None, f"{section}.{key}", table, key, new
    teams = data.get("teams")
    for team, table in (teams.items() if isinstance(teams, Mapping) else ()):
        for key, new in TEAM_MOVED.items():
            if isinstance(table, Mapping) and key in table:
                yield team, f"teams.{team}.{key}", table, key, new


def refuse_moved(data: Mapping[str, Any]) -> None:
    """ConfigError naming the first moved key of nested `data` (as parsed from TOML, `--set` applied), its value and
    the key that replaced it (or, for a removed key, what does its work now)."""
    for name, table, key in removed_keys(data):
        section, short = name.split(".")
        raise ConfigError(f"{name} was removed ({REMOVED[(section, short)]}); leave it out, got {table[key]!r}")
    for team, old, table, key, new in moved_keys(data):
        place = f"teams.<team>.priority.{new} (one per team)" if team is None else f"teams.{team}.priority.{new}"
        raise ConfigError(f"{old} moved to {place}; set that instead, got {table[key]!r}")


def migrate_moved(data: Mapping[str, Any], team_names: tuple[str, ...]) -> dict[str, Any]:
    """A copy of a stored run config's nested `data` with every moved key at its new place (module docstring);
    `team_names`: the teams when `data` has no [teams] tables (the run's defaults). Data without a moved key comes
    back equal."""
    out = {name: dict(table) if isinstance(table, Mapping) else table for name, table in data.items()}
    if isinstance(out.get("teams"), Mapping):
        out["teams"] = {team: dict(table) if isinstance(table, Mapping) else table
                        for team, table in out["teams"].items()}
    for _, table, key in list(removed_keys(out)):  # a removed key's work is done elsewhere now: dropped
        table.pop(key)
    moved: dict[str | None, dict[str, Any]] = {}  # team (None: every team) -> {key in its priority table: value}
    for team, _, table, key, new in moved_keys(out):
        moved.setdefault(team, {})[new] = table.pop(key)
    moved_global = moved.pop(None, {})
    teams = out.get("teams")
    if not isinstance(teams, Mapping):
        if not moved_global:
            return out
        teams = {name: {} for name in team_names}
    for team, table in teams.items():
        if isinstance(table, dict):
            priority = dict(table.get("priority", {}))
            for new, value in [*moved.get(team, {}).items(), *moved_global.items()]:
                priority.setdefault(new, value)
            if priority:
                table["priority"] = priority
    out["teams"] = teams
    return out

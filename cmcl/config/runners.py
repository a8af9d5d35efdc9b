"""Config keys that only one runner honours, and the check, at load time, that a run sets none its runner ignores.

Where it sits: `cmcl.run_flags.open_run` calls `check_runner_keys` once the runner is known (`python -m cmcl train
--runner inline|service`, default the service; `python -m cmcl.loop` inline, `python -m services.launch` the
service; `resume` the runner that wrote the run), before the run directory is made. Every other key is read by both
runners (they build one system from it, cmcl.system).

The table (`RUNNER_ONLY`), from reading both runners (cmcl/loop/inline.py, services/):
  service.*                          the service only: the inline runner trains in one process, without actors, Ray
                                     calls, CPU reservations or a metrics endpoint
  run.checkpoint_every               inline only: the service checkpoints every service.checkpoint_every_s seconds
  run.log_every                      inline only: the service logs a progress row every 2 s
  teachers.rescore_rows_per_update   inline only: the service's teacher and ICM calls rescore
                                     service.score_rows_per_call rows each
  icm.intrinsic_reward_coef          inline only: the service's learner holds no ICM (ablation A6)

The rule. A key of the table counts as set when the user gives it explicitly, in the config file or by `--set` (or a
flag that stands for one, `--metrics-port`), and its value differs from its default; a key the chosen runner does
not honour is then
  * refused when it comes from `--set`: a command-line override asks for this run, on this runner (one line naming
    the key, the runner and the value; exit 2);
  * refused when it comes from the config file and changes what is learned with nothing in its place on the chosen
    runner (icm.intrinsic_reward_coef on the service);
  * otherwise, from the config file, not read: a file describes a run for either runner, so it may carry the other
    runner's own way of doing what the chosen runner does its own way (configs/smoke.toml's checkpoint and log
    cadences, the paper presets' rescoring per update in configs/paper/, which the service runs too). A file's
    [service] section is simply not read inline (the section's name says whose it is); a key of another section is
    named in a one-line note on stderr, with what the chosen runner does instead, so that nothing is ignored
    silently.
A resumed run's stored config.toml was checked when the run started: only the resume's own overrides are checked.

The service-only flags of cmcl.run_flags (SERVICE_ONLY_FLAGS) are another idea, kept apart from this table: they are
flags of the command, refused from the request before any config is read, and three of them (--address, --num-cpus,
--ray-metrics-port) name no config key, while the two that do (--metrics-port, --metrics-host) reach this check as
the service.* overrides they stand for.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any, Literal

from cmcl.config.checks import ConfigError
from cmcl.config.experiment import Config
from cmcl.config.toml_io import parse_override

Runner = Literal["inline", "service"]
RUN_FLAG = {"inline": "--runner inline", "service": "--runner service"}


@dataclass(frozen=True)
class RunnerKey:
    """A key (or, as "section.*", every key of a section) honoured by `runner` only. instead: what the other runner
    does in its place; from_file: what a config file's value of it does under the other runner, "read_not" (not
    read: the other runner has its own way, `instead`) or "refused" (it changes what is learned, with nothing in its
    place)."""

    runner: Runner
    instead: str
    from_file: Literal["read_not", "refused"] = "read_not"


RUNNER_ONLY: dict[str, RunnerKey] = {
    "service.*": RunnerKey("service", "the inline runner trains in one process, without actors, Ray calls, CPU "
                                      "reservations or a metrics endpoint"),
    "run.checkpoint_every": RunnerKey("inline", "the service checkpoints every service.checkpoint_every_s seconds"),
    "run.log_every": RunnerKey("inline", "the service logs a progress row every 2 s"),
    "teachers.rescore_rows_per_update": RunnerKey(
        "inline", "the service's teacher and ICM calls rescore service.score_rows_per_call rows each"),
    "icm.intrinsic_reward_coef": RunnerKey("inline", "the service's learner holds no ICM (ablation A6)", "refused"),
}


def runner_key(key: str) -> RunnerKey | None:
    """The table's entry of a dotted key ("run.log_every", "service.metrics_port"), None if both runners read it."""
    return RUNNER_ONLY.get(key) or RUNNER_ONLY.get(f"{key.split('.')[0]}.*")


def _value(config: Config, key: str) -> Any:
    section, name = key.split(".", 1)
    return getattr(getattr(config, section), name)


def _file_keys(data: Mapping[str, Any]) -> list[str]:
    """The dotted keys of a config file's sections (not the teams': every key of the table is a section's)."""
    return [f"{section}.{name}" for section, table in data.items() if section != "teams" and isinstance(table, Mapping)
            for name in table]


def note_on_stderr(line: str) -> None:
    print(line, file=sys.stderr)


def check_runner_keys(config: Config, runner: Runner, file_data: Mapping[str, Any] | None = None,
                      overrides: Iterable[str] = (), note: Callable[[str], None] = note_on_stderr) -> None:
    """Apply the rule of the module docstring to the resolved `config` of `runner`: `file_data` the config file's
    tables (as parsed), `overrides` the `--set` strings. Raises ConfigError (one line) for a key refused; calls
    `note` with one line naming the file's keys the runner does not read (other than a [service] section's)."""
    defaults, file_data = Config(), file_data or {}
    given = [(".".join(parse_override(text)[0]), "set") for text in overrides]
    given += [(key, "file") for key in _file_keys(file_data)]
    unread = {}
    for key, source in given:
        entry = runner_key(key)
        if entry is None or entry.runner == runner or key in unread:
            continue
        value = _value(config, key)
        if value == _value(defaults, key):
            continue
        if source == "set" or entry.from_file == "refused":
            raise ConfigError(f"{key} is honoured by the {entry.runner} runner only, not the {runner} runner "
                              f"({entry.instead}); leave it out or train with {RUN_FLAG[entry.runner]}, got {value!r}")
        if not key.startswith("service."):
            unread[key] = f"{key} = {value!r} ({entry.instead})"
    if unread:
        note(f"note: the {runner} runner does not read the config file's " + "; ".join(unread.values()))

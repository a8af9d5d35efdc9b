"""Config keys that only the service runner honours, and the check, at load time, that a run sets none its runner
ignores.

Where it sits: `cmcl.run.flags.open_run` calls `check_runner_keys` once the runner is known (`python -m cmcl train
--runner inline|service`, default the service; `python -m services.launch` the service; `resume` the runner that
wrote the run), before the run directory is made. Both runners schedule the same roles (services.runtime.calls: Ray
actors, or the same objects in this process), so every other key is read by both.

The table (`RUNNER_ONLY`): the service's Ray-only keys. In one process there is no actor to place, reserve CPUs
for, restart or time out, and no metrics endpoint:
  service.max_restarts, service.call_timeout_s, service.rollout_resource,
  service.{rollout,learner,teacher,icm,replay}_cpus, service.metrics_port, service.metrics_host

The rule. A key of the table counts as set when the user gives it explicitly, in the config file or by `--set` (or a
flag that stands for one, `--metrics-port`), and its value differs from its default; a key the chosen runner does
not honour is then
  * refused when it comes from `--set`: a command-line override asks for this run, on this runner (one line naming
    the key, the runner and the value; exit 2);
  * from the config file, not read inline: a file describes a run for either runner (the deploy files' CPU
    requests).
A resumed run's stored config.toml was checked when the run started: only the resume's own overrides are checked.

The service-only flags of cmcl.run.flags (SERVICE_ONLY_FLAGS) are another idea, kept apart from this table: they are
flags of the command, refused from the request before any config is read, and three of them (--address, --num-cpus,
--ray-metrics-port) name no config key, while the two that do (--metrics-port, --metrics-host) reach this check as
the service.* overrides they stand for.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any, Literal

from cmcl.config.checks import ConfigError
from cmcl.config.experiment import Config
from cmcl.config.toml_io import parse_override

Runner = Literal["inline", "service"]
RUN_FLAG = {"inline": "--runner inline", "service": "--runner service"}


# the service's Ray-only keys, and what the inline runner does instead
SERVICE_ONLY = frozenset(f"service.{key}" for key in (
    "max_restarts", "call_timeout_s", "rollout_resource", "rollout_cpus", "learner_cpus", "teacher_cpus", "icm_cpus",
    "replay_cpus", "metrics_port", "metrics_host"))
IN_ONE_PROCESS = ("the inline runner runs every role in this process: no actor to place, restart or time out, no "
                  "metrics endpoint")


def _value(config: Config, key: str) -> Any:
    section, name = key.split(".", 1)
    return getattr(getattr(config, section), name)


def check_runner_keys(config: Config, runner: Runner, file_data: Mapping[str, Any] | None = None,
                      overrides: Iterable[str] = ()) -> None:
    """Apply the rule of the module docstring to the resolved `config` of `runner`: `file_data` the config file's
    tables (as parsed, unused: a file's service-only keys are not read inline), `overrides` the `--set` strings.
    Raises ConfigError (one line) for a service-only key set by `--set` on the inline runner."""
    if runner == "service":
        return
    defaults = Config()
    for text in overrides:
        key = ".".join(parse_override(text)[0])
        if key in SERVICE_ONLY and (value := _value(config, key)) != _value(defaults, key):
            raise ConfigError(f"{key} is honoured by the service runner only, not the inline runner "
                              f"({IN_ONE_PROCESS}); leave it out or train with {RUN_FLAG['service']}, got {value!r}")

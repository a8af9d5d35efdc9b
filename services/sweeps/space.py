"""The search space of a sweep (`python -m cmcl tune --search KEY=DISTRIBUTION`): each flag parsed into a typed
`Dimension`, checked against the config schema before any trial starts, and turned into a Ray Tune domain.

Distributions (the bounds are numbers; `choice` takes TOML values, bare words are strings):

    loguniform(a, b)   a float with log(x) uniform on [log a, log b], 0 < a < b
    uniform(a, b)      a float uniform on [a, b], a < b
    randint(a, b)      an integer uniform on a, a+1, ..., b (both ends included), a <= b
    choice(x, y, ...)  one of the listed values, each equally likely

A trial's values become `--set KEY=VALUE` overrides of its run (`override`), and the best trial's are printed as
`--set` flags ready to paste (`set_flag`). Ray is imported only by `Dimension.domain`.
"""

from __future__ import annotations

import math
import re
import shlex
import tomllib
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from cmcl.config import Config, ConfigError, apply_overrides, config_from_dict, load_data, parse_override
from cmcl.config.runners import Runner, check_runner_keys

DISTRIBUTIONS = ("loguniform", "uniform", "randint", "choice")
_CALL = re.compile(r"^\s*([a-z]+)\s*\((.*)\)\s*$", re.DOTALL)


class SweepError(ValueError):
    """A sweep's flags that cannot be honoured; the message (one line) names the flag and its value."""


@dataclass(frozen=True)
class Dimension:
    """One searched config key. key: dotted config key ("maddpg.actor_lr"); kind: one of DISTRIBUTIONS; values:
    the bounds (low, high) of a range, or the options of a choice; text: the flag as given, for error lines."""

    key: str
    kind: str
    values: tuple[Any, ...]
    text: str

    def probes(self) -> tuple[Any, ...]:
        """The values a config must accept for every sample of this dimension to be valid: both bounds, or every
        option."""
        return self.values

    def domain(self) -> Any:
        """This dimension as a Ray Tune search domain (`randint`'s upper bound made inclusive)."""
        from ray import tune

        if self.kind == "loguniform":
            return tune.loguniform(*self.values)
        if self.kind == "uniform":
            return tune.uniform(*self.values)
        if self.kind == "randint":
            return tune.randint(self.values[0], self.values[1] + 1)
        return tune.choice(list(self.values))


def _value(raw: str) -> Any:
    """One argument of a distribution: a TOML value, or the bare word itself as a string."""
    try:
        return tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        return raw.strip()


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def parse_search(text: str) -> Dimension:
    """`KEY=DISTRIBUTION` (the value of one --search flag) as a Dimension; SweepError naming the flag otherwise."""
    where = f"--search {text}"
    key, sep, spec = text.partition("=")
    key = key.strip()
    if not sep or not key:
        raise SweepError(f"{where}: must look like section.key=distribution, e.g. "
                         "maddpg.actor_lr=loguniform(1e-4,1e-2)")
    try:
        parse_override(f"{key}=0")
    except ConfigError as err:
        raise SweepError(f"{where}: {err}") from None
    call = _CALL.match(spec)
    if call is None or call.group(1) not in DISTRIBUTIONS:
        raise SweepError(f"{where}: the distribution must be one of {', '.join(f'{d}(...)' for d in DISTRIBUTIONS)}, "
                         f"got {spec.strip()!r}")
    kind, inner = call.group(1), call.group(2)
    values = tuple(_value(part) for part in inner.split(",")) if inner.strip() else ()
    if kind == "choice":
        if not values or any(isinstance(v, list | dict) for v in values):
            raise SweepError(f"{where}: choice takes one or more scalar values, got {inner.strip()!r}")
        return Dimension(key, kind, values, text)
    if len(values) != 2 or not all(_is_number(v) for v in values):
        raise SweepError(f"{where}: {kind} takes two numbers (low, high), got {inner.strip()!r}")
    low, high = values
    if kind == "randint":
        if not all(isinstance(v, int) for v in values) or low > high:
            raise SweepError(f"{where}: randint takes two integers low <= high, got {inner.strip()!r}")
    elif not low < high:
        raise SweepError(f"{where}: {kind} needs low < high, got {inner.strip()!r}")
    elif kind == "loguniform" and low <= 0:
        raise SweepError(f"{where}: loguniform needs 0 < low, got {inner.strip()!r}")
    return Dimension(key, kind, (low, high) if kind == "randint" else (float(low), float(high)), text)


def toml_literal(value: Any) -> str:
    """`value` (a sampled scalar: bool, int, float or str; numpy scalars too) as a TOML literal."""
    value = value.item() if hasattr(value, "item") else value
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    return repr(value)


def override(key: str, value: Any) -> str:
    """The `section.key=value` override that sets `key` to the sampled `value`."""
    return f"{key}={toml_literal(value)}"


def set_flag(key: str, value: Any) -> str:
    """`--set key=value`, quoted for a POSIX shell where it needs it."""
    return f"--set {shlex.quote(override(key, value))}"


def check_space(dimensions: Iterable[Dimension], config_file: str | None, overrides: tuple[str, ...],
                reserved: dict[str, str], runner: Runner = "inline") -> Config:
    """Refuse, in one line naming the flag, a dimension whose key the config schema does not know, whose values
    it refuses (each bound, each option: ConfigError's words), that the trials' `runner` does not read (the
    service's Ray-only keys on inline trials), that is searched twice, or that the sweep sets itself (`reserved`:
    key -> why). Returns the config of the first probe of every dimension (the sweep's fixed settings checked
    too)."""
    dimensions = list(dimensions)
    seen: set[str] = set()
    for dim in dimensions:
        if dim.key in seen:
            raise SweepError(f"--search {dim.text}: {dim.key} is searched twice")
        seen.add(dim.key)
        if dim.key in reserved:
            raise SweepError(f"--search {dim.text}: {dim.key} is set by the sweep ({reserved[dim.key]})")
    file_data = load_data(config_file)
    base = apply_overrides(file_data, overrides)
    config = config_from_dict(base)  # the fixed settings alone: their own error first
    check_runner_keys(config, runner, file_data, overrides)
    for dim in dimensions:
        for probe in dim.probes():
            sets = (*overrides, override(dim.key, probe))
            try:
                probed = config_from_dict(apply_overrides(file_data, sets))
                check_runner_keys(probed, runner, file_data, sets)
            except ConfigError as err:
                raise SweepError(f"--search {dim.text}: {err}") from None
    firsts = (*overrides, *(override(d.key, d.probes()[0]) for d in dimensions))
    return config_from_dict(apply_overrides(file_data, firsts))

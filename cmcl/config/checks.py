"""The checks every config section runs on its values: each failure is a `ConfigError` whose message starts with the
full key (``maddpg.gamma``) and ends with the value (``got 3.0``).

A field's range check is a `Rule` in its metadata (cmcl.field_docs.documented); `check_fields` runs a section's
rules in field order. A rule's `why` is the message's text and the allowed range `python -m cmcl config` prints.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from cmcl.field_docs import ruled_fields


class ConfigError(ValueError):
    """A configuration key is unknown, of the wrong type, or out of range."""


def _require(ok: bool, key: str, value: Any, why: str) -> None:
    """Raise ConfigError('<key> <why>, got <value>') unless ok."""
    if not ok:
        raise ConfigError(f"{key} {why}, got {value!r}")


@dataclass(frozen=True)
class Rule:
    """The range check of one config field: `ok(value, section)` (`section`: the whole section dataclass, for a
    range that depends on another field of it) says whether `value` passes; `why` is the ConfigError's text."""

    why: str
    ok: Callable[[Any, Any], bool]


def rule(why: str, ok: Callable[[Any], bool]) -> Rule:
    """A Rule on the value alone."""
    return Rule(why, lambda value, _section: ok(value))


AT_LEAST_1 = rule("must be >= 1", lambda v: v >= 1)
AT_LEAST_0 = rule("must be >= 0", lambda v: v >= 0)
FINITE_AT_LEAST_0 = rule("must be a finite number >= 0", lambda v: v >= 0 and math.isfinite(v))
POSITIVE = rule("must be a finite number > 0", lambda v: v > 0 and math.isfinite(v))
PROBABILITY = rule("must lie in [0, 1]", lambda v: 0 <= v <= 1)
OPEN_PROBABILITY = rule("must lie in (0, 1]", lambda v: 0 < v <= 1)
OPTIONAL_ALPHA = rule("must be a finite number >= 0 (or unset: the per-algorithm default)",
                      lambda v: v is None or (v >= 0 and math.isfinite(v)))


def check_fields(section: Any, name: str) -> None:
    """Run the rule of every field of the section dataclass `section` (named `name` in keys), in field order."""
    for field_name, value, field_rule in ruled_fields(section):
        _require(field_rule.ok(value, section), f"{name}.{field_name}", value, field_rule.why)

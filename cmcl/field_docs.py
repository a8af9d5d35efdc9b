"""Documented fields: every field of a configuration dataclass carries its meaning, unit and range check in its own
metadata, declared with `documented(default, meaning, unit=..., rule=...)`.

Where it sits: the one place a config field is documented. The run configuration's sections (cmcl.config.learning,
cmcl.config.teams, cmcl.config.run_and_service, cmcl.config.env) and the world parameters (cmcl.envs.params)
declare their fields with it; their `__post_init__` run the fields' rules (`ruled_fields`), whose `why` is both the
error message's text ("must be >= 1") and the allowed range that `python -m cmcl config` and docs/CONFIG.md print
(cmcl.config.reference). Standard library only, so that cmcl.envs can use it without importing cmcl.config.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator
from typing import Any, Protocol

MEANING, UNIT, RULE = "meaning", "unit", "rule"


class Rule(Protocol):
    """A field's range check; `why` is the text its error messages use ("<key> <why>, got <value>")."""

    @property
    def why(self) -> str: ...


def documented(default: Any = dataclasses.MISSING, meaning: str = "", *, unit: str = "", rule: Rule | None = None,
               factory: Callable[[], Any] | None = None) -> Any:
    """A dataclass field with default `default` (or `factory()`), its meaning, unit ("" = none) and range check."""
    metadata = {MEANING: meaning, UNIT: unit, RULE: rule}
    if factory is not None:
        return dataclasses.field(default_factory=factory, metadata=metadata)
    return dataclasses.field(default=default, metadata=metadata)


def ruled_fields(obj: Any) -> Iterator[tuple[str, Any, Any]]:
    """(name, value, rule) of each field of dataclass instance `obj` that has a rule, in field order."""
    for f in dataclasses.fields(obj):
        rule = f.metadata.get(RULE)
        if rule is not None:
            yield f.name, getattr(obj, f.name), rule

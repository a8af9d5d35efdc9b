"""The checks every config section runs on its values: each failure is a `ConfigError` whose message starts with the
full key (``maddpg.gamma``) and ends with the value (``got 3.0``)."""

from __future__ import annotations

import math
from typing import Any


class ConfigError(ValueError):
    """A configuration key is unknown, of the wrong type, or out of range."""


def _require(ok: bool, key: str, value: Any, why: str) -> None:
    """Raise ConfigError('<key> <why>, got <value>') unless ok."""
    if not ok:
        raise ConfigError(f"{key} {why}, got {value!r}")


def _positive(key: str, value: float) -> None:
    _require(value > 0 and math.isfinite(value), key, value, "must be a finite number > 0")


def _probability(key: str, value: float, *, open_low: bool = False) -> None:
    ok = (0 < value <= 1) if open_low else (0 <= value <= 1)
    _require(ok, key, value, "must lie in (0, 1]" if open_low else "must lie in [0, 1]")

"""The tiny config: a preset shrunk so that a run takes seconds, defined once for every test module.

Tests take it as the fixture `tiny_config` (tests/conftest.py); a module-scoped fixture or a helper script that
cannot take a function-scoped fixture imports `make_tiny_config` from here.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from cmcl.config import Config, config_from_dict, preset

# Each preset's settings that make a run take seconds: 4 parallel worlds, a 96-transition warm-up, 16-row batches,
# 32-unit networks and a 600-row buffer; 12 episodes.
TINY_SECTIONS: dict[str, dict[str, Any]] = {
    "env": {"num_envs": 4},
    "maddpg": {"batch_size": 16, "warmup": 96, "hidden": 32},
    "replay": {"capacity": 600},
    "teachers": {"batch_size": 16, "hidden": 32},
    "icm": {"batch_size": 16},
    "run": {"episodes": 12, "smoothing_window": 8},
}


def make_tiny_config(algorithm: str = "cmcl", task: str = "spread", opponent: str = "maddpg", *,
                     sections: Mapping[str, Mapping[str, Any]] = (), **run: Any) -> Config:
    """`preset(algorithm, task, opponent)` with `TINY_SECTIONS`, then `sections` ({section: {key: value}}), then
    `run` (run-section values: dir, episodes, ...) on top."""
    data = preset(algorithm, task, opponent).to_dict()
    for layer in (TINY_SECTIONS, dict(sections), {"run": run}):
        for section, values in layer.items():
            data[section].update(values)
    return config_from_dict(data)

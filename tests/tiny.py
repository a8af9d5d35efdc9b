"""The tiny config: a preset shrunk so that a run takes seconds, defined once for every test module.

Tests take it as the fixture `tiny_config` (tests/conftest.py); a module-scoped fixture or a helper script that
cannot take a function-scoped fixture imports `make_tiny_config` from here. A run through the service adds
`service=True` (its settings below); a command line takes the same settings as `--set` overrides from
`tiny_overrides`. A test that needs a different value passes it (`sections=`, or a run-section keyword) and says
why next to it.
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

# On top, for a run through the service (the tests' embedded Ray has 2 CPUs): 3 teacher folds (3 actors, or the
# automatic single stacked one), calls of 8 learner updates / 4 teacher fit steps / 256 scored rows, a free metrics
# port (0: any), 2 restarts per actor (the fault tests count them), and no timed checkpoint within a test's seconds.
TINY_SERVICE_SECTIONS: dict[str, dict[str, Any]] = {
    "teachers": {"num_folds": 3},
    "service": {"updates_per_call": 8, "fit_steps_per_call": 4, "score_rows_per_call": 256, "metrics_port": 0,
                "max_restarts": 2, "checkpoint_every_s": 3600.0},
}


def tiny_layers(service: bool = False) -> list[dict[str, dict[str, Any]]]:
    """The tiny settings as {section: {key: value}} layers, applied in order: `TINY_SECTIONS`, then (`service`)
    `TINY_SERVICE_SECTIONS`."""
    return [TINY_SECTIONS, TINY_SERVICE_SECTIONS] if service else [TINY_SECTIONS]


def make_tiny_config(algorithm: str = "cmcl", task: str = "spread", opponent: str = "maddpg", *,
                     service: bool = False, sections: Mapping[str, Mapping[str, Any]] = (), **run: Any) -> Config:
    """`preset(algorithm, task, opponent)` with the tiny settings (`tiny_layers(service)`), then `sections`
    ({section: {key: value}}), then `run` (run-section values: dir, episodes, ...) on top."""
    data = preset(algorithm, task, opponent).to_dict()
    for layer in (*tiny_layers(service), dict(sections), {"run": run}):
        for section, values in layer.items():
            data[section].update(values)
    return config_from_dict(data)


def tiny_overrides(service: bool = False) -> list[str]:
    """The tiny settings as command-line overrides (`section.key=value`, for `load_config` or `--set`), in the
    order of `tiny_layers(service)`; a later override of the same key wins."""
    return [f"{section}.{key}={value!r}" for layer in tiny_layers(service) for section, values in layer.items()
            for key, value in values.items()]

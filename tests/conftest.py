"""Shared fixtures. Service tests share ONE embedded 2-CPU Ray for the whole session, shut down at the end. The
tiny config (a preset shrunk so that a run takes seconds) is built here once, for every test module."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import pytest

from cmcl.config import Config, config_from_dict, dump_toml, preset

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


@pytest.fixture
def tiny_config() -> Callable[..., Config]:
    """The factory `make_tiny_config(algorithm, task, opponent, sections=..., **run) -> Config`. A module that needs
    more settings of its own overrides this fixture with a `functools.partial` of it (see tests/test_loop.py)."""
    return make_tiny_config


@pytest.fixture
def tiny_config_file(tiny_config, tmp_path) -> Callable[..., Path]:
    """Write a tiny config as TOML for a command line (`--config FILE`): the same arguments as `tiny_config`;
    returns the file's path."""

    def write(*args: Any, **kwargs: Any) -> Path:
        path = tmp_path / "tiny.toml"
        path.write_text(dump_toml(tiny_config(*args, **kwargs)))
        return path

    return write


@pytest.fixture(scope="session")
def ray_cluster():
    """A real embedded Ray (2 CPUs, no dashboard) for the service tests; started once, shut down at the end."""
    ray = pytest.importorskip("ray")
    if not ray.is_initialized():
        ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()

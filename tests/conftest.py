"""Shared fixtures. Service tests share ONE embedded 2-CPU Ray for the whole session, shut down at the end. The
tiny config (a preset shrunk so that a run takes seconds, tests/tiny.py) is a fixture here, for every test module.

`make test` runs the suite in two processes (pytest-xdist, `-n 2 --dist loadfile`): a module's tests run in one of
them, so its module-scoped fixtures (e.g. the live Prometheus) start once; each process that runs a service test
starts its own session Ray. (`--dist loadgroup` would keep the service tests on one Ray, but pytest-xdist 3.8 cannot
group under pytest 9.2: the group suffix it writes to `item._nodeid` is no longer what `nodeid` reads.)"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from cmcl.config import Config, dump_toml
from services.runtime.loopback import LOOPBACK_ENV, loopback_only
from tests.tiny import make_tiny_config


@pytest.fixture
def tiny_config() -> Callable[..., Config]:
    """The factory `make_tiny_config(algorithm, task, opponent, service=..., sections=..., **run) -> Config`. A
    module that needs more settings of its own overrides this fixture with a `functools.partial` of it (see
    tests/test_loop.py)."""
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
    """A real embedded Ray (2 CPUs, no dashboard, every server on 127.0.0.1) for the service tests; started once,
    shut down at the end."""
    ray = pytest.importorskip("ray")
    if not ray.is_initialized():
        saved = {key: os.environ.get(key) for key in LOOPBACK_ENV}
        loopback_only()  # as the launcher's embedded Ray: every server on 127.0.0.1
        ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
        for key, value in saved.items():  # Ray's processes have it; a test's own `ray start` (a cluster) must not
            if value is None:
                os.environ.pop(key)
            else:
                os.environ[key] = value
    yield ray
    ray.shutdown()

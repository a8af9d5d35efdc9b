"""Shared fixtures. Service tests share ONE embedded 2-CPU Ray for the whole session, shut down at the end."""

import pytest


@pytest.fixture(scope="session")
def ray_cluster():
    """A real embedded Ray (2 CPUs, no dashboard) for the service tests; started once, shut down at the end."""
    ray = pytest.importorskip("ray")
    if not ray.is_initialized():
        ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()

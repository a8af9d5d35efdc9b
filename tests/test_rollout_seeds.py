"""A rollout worker's worlds: the seed's own in a new run (one process's runs repeat exactly), other worlds in each
resumed segment (services.runtime.placement.resumed_episodes), and other worlds again after a Ray restart (its
incarnation)."""

import numpy as np

from services.roles.rollout import RolloutWorker
from tests.in_process import in_process_config


def first_observations(resumed_at=0):
    return RolloutWorker(in_process_config("maddpg"), 0, 0, resumed_at).obs


def test_a_new_run_repeats_its_worlds_and_a_resumed_segment_does_not():
    np.testing.assert_array_equal(first_observations(), first_observations())
    assert not np.allclose(first_observations(), first_observations(resumed_at=12))
    np.testing.assert_array_equal(first_observations(12), first_observations(12))

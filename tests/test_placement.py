"""services/runtime/placement.py: the Ray placement policy (teacher folds per actor, CPU budget) without a cluster."""

import pytest

from cmcl.config import load_config, preset
from services.runtime.placement import required_cpus, teacher_groups


def test_teacher_actor_groups():
    config = preset("cmcl")
    assert teacher_groups(config) == [[0], [1], [2], [3], [4]]
    assert teacher_groups(config, cluster_cpus=2) == [[0, 1, 2, 3, 4]], "automatic: one stacked actor on 2 cores"
    assert teacher_groups(config, cluster_cpus=16) == [[0], [1], [2], [3], [4]]
    two = load_config(None, ["service.teacher_actors=2"])
    assert teacher_groups(two, cluster_cpus=2) == [[0, 2, 4], [1, 3]]


@pytest.mark.parametrize(("algorithm", "cpus"), [("maddpg", 1.0), ("acl", 1.1), ("cmcl", 1.2)])
def test_required_cpus_counts_only_the_roles_a_config_starts(algorithm, cpus):
    # rollout 0.25 + learner 0.5 + replay 0.25, + 0.1 per teacher actor (one on 2 CPUs), + 0.1 for the ICM
    assert required_cpus(preset(algorithm), cluster_cpus=2) == pytest.approx(cpus)
    assert required_cpus(preset("cmcl"), cluster_cpus=None) == pytest.approx(1.0 + 5 * 0.1 + 0.1)

"""The numpy actor of the rollout workers computes exactly MADDPG.act (continuous actions)."""

import numpy as np
import pytest

from cmcl.learners.maddpg import MADDPG
from cmcl.learners.policy import NumpyPolicy
from cmcl.learners.weights import load_published, published_weights


@pytest.mark.parametrize("share", [False, True])
@pytest.mark.parametrize("noise", [0.0, 0.1])
def test_numpy_policy_matches_maddpg_act(noise, share):
    maddpg = MADDPG(4, 18, seed=3, share_parameters=share)
    obs = np.random.default_rng(0).normal(size=(64, 4, 18)).astype(np.float32)
    policy = NumpyPolicy(published_weights(maddpg)["actor"])
    ours = policy.act(obs, noise, rng=np.random.default_rng(7))
    theirs = maddpg.act(obs, noise, rng=np.random.default_rng(7))
    np.testing.assert_allclose(ours, theirs, atol=1e-5)
    assert ours.dtype == np.float32 and ours.shape == (64, 4, 2) and np.abs(ours).max() <= 1.0


def test_bad_weights_are_refused():
    weights = published_weights(MADDPG(2, 6, seed=0))["actor"]
    with pytest.raises(ValueError, match="layers"):
        NumpyPolicy({k: v for k, v in weights.items() if not k.startswith("layers.1")})
    broken = dict(weights)
    broken["layers.0.bias"] = np.full_like(weights["layers.0.bias"], np.nan)
    with pytest.raises(ValueError, match="finite"):
        NumpyPolicy(broken)


def test_published_weights_round_trip_into_another_learner():
    source, target = MADDPG(3, 10, seed=1), MADDPG(3, 10, seed=2)
    load_published(target, published_weights(source))
    obs = np.ones((5, 3, 10), np.float32)
    np.testing.assert_array_equal(target.act(obs, 0.0), source.act(obs, 0.0))
    with pytest.raises(ValueError, match="shape"):
        bad = published_weights(source)
        bad["actor"]["layers.0.weight"] = bad["actor"]["layers.0.weight"][:, :5]
        load_published(target, bad)


@pytest.mark.parametrize("pool", ["attention", "mean", "relational"])
@pytest.mark.parametrize("noise", [0.0, 0.1])
def test_numpy_entity_policy_matches_maddpg_act(noise, pool):
    from cmcl.envs.entities import spread_layout, tag_layout
    from cmcl.envs.params import TagParams
    from cmcl.learners.policy import NumpyEntityPolicy, numpy_policy

    for layout in (spread_layout(5), spread_layout(5, agent_tags=True), tag_layout(TagParams())):
        n, od = layout.num_agents, layout.obs_dim
        maddpg = MADDPG(n, od, seed=3, networks="entity", entity_layout=layout, entity_pool=pool)
        obs = np.random.default_rng(0).normal(size=(32, n, od)).astype(np.float32)
        policy = numpy_policy(published_weights(maddpg)["actor"], entities=layout)
        assert isinstance(policy, NumpyEntityPolicy)
        ours = policy.act(obs, noise, rng=np.random.default_rng(7))
        theirs = maddpg.act(obs, noise, rng=np.random.default_rng(7))
        np.testing.assert_allclose(ours, theirs, atol=1e-5)
        assert ours.dtype == np.float32 and ours.shape == (32, n, 2)
    with pytest.raises(ValueError, match="entity layout"):
        numpy_policy(published_weights(maddpg)["actor"])

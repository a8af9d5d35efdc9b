"""The numpy actor of the rollout workers computes exactly MADDPG.act (continuous actions)."""

import numpy as np
import pytest

from cmcl.learners.maddpg import MADDPG
from cmcl.learners.weights import load_published, published_weights
from cmcl.rollout.policy import NumpyPolicy, numpy_policy


@pytest.mark.parametrize("share", [False, True])
@pytest.mark.parametrize("noise", [0.0, 0.1])
def test_numpy_policy_matches_maddpg_act(noise, share):
    maddpg = MADDPG(4, 18, seed=3, networks="shared" if share else "per_agent")
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


def entity_layouts():
    """Navigation at N = 5 (with and without agent tags), N = 2 (fewer landmarks and agents than k = 3) and
    predator-prey (one prey, two obstacles: fewer than k = 3)."""
    from cmcl.envs.entities import spread_layout, tag_layout
    from cmcl.envs.params import TagParams

    return (spread_layout(5), spread_layout(5, agent_tags=True), spread_layout(2), tag_layout(TagParams()))


@pytest.mark.parametrize("nearest", [0, 1, 3])
@pytest.mark.parametrize("pool", ["attention", "mean", "relational"])
@pytest.mark.parametrize("noise", [0.0, 0.1])
def test_numpy_entity_policy_matches_maddpg_act(noise, pool, nearest):
    from cmcl.rollout.policy import NumpyEntityPolicy

    for layout in entity_layouts():
        n, od = layout.num_agents, layout.obs_dim
        maddpg = MADDPG(n, od, seed=3, networks="entity", entity_layout=layout, entity_pool=pool,
                        entity_nearest=nearest)
        obs = np.random.default_rng(0).normal(size=(32, n, od)).astype(np.float32)
        policy = numpy_policy(published_weights(maddpg)["actor"], entities=layout, nearest=nearest)
        assert isinstance(policy, NumpyEntityPolicy)
        ours = policy.act(obs, noise, rng=np.random.default_rng(7))
        theirs = maddpg.act(obs, noise, rng=np.random.default_rng(7))
        np.testing.assert_allclose(ours, theirs, atol=1e-5)
        assert ours.dtype == np.float32 and ours.shape == (32, n, 2)
    with pytest.raises(ValueError, match="entity layout"):
        numpy_policy(published_weights(maddpg)["actor"])


@pytest.mark.parametrize("nearest", [0, 1, 3])
@pytest.mark.parametrize("pool", ["attention", "relational"])
def test_numpy_entity_policy_matches_the_actor_on_rows_of_fewer_agents(pool, nearest):
    """Rows carried from fewer agents (run.carry_replay): the absent agents' entities are masked before the pick."""
    import torch

    from cmcl.envs.entities import spread_layout

    layout = spread_layout(5)
    maddpg = MADDPG(5, layout.obs_dim, seed=1, networks="entity", entity_layout=layout, entity_pool=pool,
                    entity_nearest=nearest)
    rng = np.random.default_rng(2)
    obs = rng.normal(size=(40, 5, layout.obs_dim)).astype(np.float32)
    count = np.repeat(rng.integers(1, 6, size=(40, 1)), 5, axis=1)  # [B, N]: the first count agents present
    policy = numpy_policy(published_weights(maddpg)["actor"], entities=layout, nearest=nearest)
    with torch.no_grad():
        theirs = maddpg.actor(torch.from_numpy(obs).transpose(0, 1), count=torch.from_numpy(count.T)).numpy()
    np.testing.assert_allclose(policy.mean_action(obs, count), theirs.transpose(1, 0, 2), atol=1e-5)
    assert not np.allclose(policy.mean_action(obs, count), policy.mean_action(obs))  # the mask is used


def test_the_nearest_picks_agree_with_the_learners_including_ties():
    """Closest first within a kind, ties to the lower slot, absent entities last (their contents unread)."""
    import torch

    from cmcl.learners.entity import picks
    from cmcl.rollout.policy import nearest_entities

    types = slice(2, 4)
    rng = np.random.default_rng(5)
    pos = rng.integers(-2, 3, size=(64, 9, 2)).astype(np.float32)  # small integers: many equal distances
    kind = rng.integers(0, 2, size=(64, 9))
    ents = np.concatenate([pos, np.eye(2, dtype=np.float32)[kind]], -1)
    mask = rng.random((64, 9)) < 0.8
    for k in (1, 3, 9, 12):
        ours, ours_mask = nearest_entities(ents, mask, k, types)
        theirs, theirs_mask = picks.nearest_entities(torch.from_numpy(ents), torch.from_numpy(mask), k, types)
        np.testing.assert_array_equal(ours_mask, theirs_mask.numpy())
        np.testing.assert_array_equal(ours[ours_mask], theirs.numpy()[ours_mask])
        assert ours.shape == (64, 2 * min(k, 9), 4)
    first, first_mask = nearest_entities(np.array([[[1, 0, 1, 0], [0, 1, 1, 0], [0, 0, 0, 1]]], np.float32),
                                         np.array([[True, True, False]]), 2, types)
    np.testing.assert_array_equal(first[0, :2, :2], [[1, 0], [0, 1]])  # a tie: slot 0 before slot 1
    np.testing.assert_array_equal(first_mask, [[True, True, False, False]])  # the absent kind: masked


def test_nearest_needs_entity_weights():
    with pytest.raises(ValueError, match="nearest entities"):
        numpy_policy(published_weights(MADDPG(2, 6, seed=0))["actor"], nearest=2)

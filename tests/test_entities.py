"""The entity view of the flat observations (cmcl.envs.entities) against the worlds' own state."""

import numpy as np
import pytest
import torch

from cmcl.envs.batched_spread import BatchedSparseSpread
from cmcl.envs.batched_tag import BatchedSparseTag
from cmcl.envs.entities import ABSENT, entity_layout, spread_layout, tag_layout
from cmcl.envs.params import SpreadParams, TagParams


def _stepped(env, steps=3, seed=0):
    rng = np.random.default_rng(seed)
    obs = env.reset()
    for _ in range(steps):
        obs, *_ = env.step(rng.uniform(-1, 1, (env.num_envs, env.num_agents, 2)).astype(np.float32))
    return obs


@pytest.mark.parametrize("n", [3, 8])
def test_spread_split_is_the_world_state(n):
    env = BatchedSparseSpread(4, SpreadParams(num_agents=n), seed=1)
    obs = _stepped(env)
    layout = spread_layout(n)
    own, ents, mask = layout.split(obs)
    assert own.shape == (4, n, 4) and ents.shape == (4, n, 2 * n - 1, 4) and mask.all()
    pos, vel, lm = (a.transpose(2, 0, 1) for a in (env._pos, env._vel, env._lm))  # [B, N|L, 2]
    np.testing.assert_allclose(own[..., :2], vel, atol=1e-6)
    np.testing.assert_allclose(own[..., 2:], pos, atol=1e-6)
    np.testing.assert_allclose(ents[:, :, :n, :2], lm[:, None] - pos[:, :, None], atol=1e-6)
    for i in range(n):
        others = [j for j in range(n) if j != i]
        np.testing.assert_allclose(ents[:, i, n:, :2], pos[:, others] - pos[:, i : i + 1], atol=1e-6)
        assert layout.entity_agent[i].tolist() == [-1] * n + others
    assert (ents[:, :, :n, 2] == 1).all() and (ents[:, :, n:, 3] == 1).all()
    assert (ents[:, :, :n, 3] == 0).all() and (ents[:, :, n:, 2] == 0).all()


@pytest.mark.parametrize("n", [3, 8])
def test_spread_split_uses_every_flat_column_once(n):
    """The split is a bijection onto the flat columns: nothing dropped, nothing read twice."""
    layout = spread_layout(n)
    for i in range(n):
        cols = np.concatenate([layout.own_index[i], layout.entity_index[i].ravel()])
        assert sorted(cols.tolist()) == list(range(layout.obs_dim))


def test_split_takes_torch_and_numpy_alike():
    layout = spread_layout(4)
    obs = np.random.default_rng(0).normal(size=(2, 5, 4, layout.obs_dim)).astype(np.float32)
    for a, b in zip(layout.split(obs), layout.split(torch.from_numpy(obs)), strict=True):
        np.testing.assert_array_equal(a, b.numpy())
    with pytest.raises(ValueError, match="obs_dim"):
        layout.split(obs[..., :-1])


def test_tag_split_is_the_world_state():
    params = TagParams(num_predators=2, num_prey=3, num_obstacles=2)
    env = BatchedSparseTag(3, params, seed=2)
    obs = _stepped(env)
    layout = tag_layout(params)
    own, ents, mask = layout.split(obs)
    n, m, o = params.num_agents, params.num_predators, params.num_obstacles
    assert own.shape == (3, n, 6) and ents.shape == (3, n, o + n - 1, 7) and mask.all()
    pos, vel, ob = (a.transpose(2, 0, 1) for a in (env._pos, env._vel, env._lm))
    np.testing.assert_allclose(own[..., 2:4], pos, atol=1e-6)
    assert (own[:, :m, 4] == 1).all() and (own[:, m:, 5] == 1).all()
    np.testing.assert_allclose(ents[:, :, :o, :2], ob[:, None] - pos[:, :, None], atol=1e-6)
    assert (ents[:, :, :o, 2:4] == 0).all() and (ents[:, :, :o, 4] == 1).all()
    for i in range(n):
        for k, j in enumerate(jj for jj in range(n) if jj != i):
            row = ents[:, i, o + k]
            np.testing.assert_allclose(row[:, :2], pos[:, j] - pos[:, i], atol=1e-6)
            np.testing.assert_allclose(row[:, 2:4], vel[:, j] if j >= m else 0.0, atol=1e-6)
            assert (row[:, 5 if j < m else 6] == 1).all() and layout.entity_agent[i, o + k] == j
        assert (layout.entity_agent[i, :o] == -1).all()


def test_entity_layout_dispatch():
    assert entity_layout(SpreadParams(num_agents=5)).num_entities == 9
    assert entity_layout(TagParams()).entity_dim == 7
    assert entity_layout(object()) is None
    assert (tag_layout(TagParams()).entity_index[:, :, 2:] == ABSENT).any()


def test_split_of_some_agents_is_their_rows_of_the_full_split():
    layout = tag_layout(TagParams(num_predators=2, num_prey=2, num_obstacles=1))
    obs = np.random.default_rng(1).normal(size=(3, layout.num_agents, layout.obs_dim)).astype(np.float32)
    full = layout.split(obs)
    some = layout.split(obs[:, [3, 1]], agents=[3, 1])
    for a, b in zip(full, some, strict=True):
        np.testing.assert_array_equal(a[:, [3, 1]], b)
    with pytest.raises(ValueError, match="A=2"):
        layout.split(obs, agents=[3, 1])

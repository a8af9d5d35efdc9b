"""Entity ICM (icm.networks = "entity"): one encoder, inverse and forward model for every curiosity agent."""

import numpy as np
import pytest
import torch

from cmcl.envs.entities import spread_layout
from cmcl.scorers.icm import ICM
from tests.test_entity_nets import spread_obs, world

torch.set_num_threads(1)


def entity_icm(n, agents, seed=0):
    layout = spread_layout(n)
    return ICM(len(agents), layout.obs_dim, 2, hidden=32, seed=seed, networks="entity", agents=agents,
               entity_layout=layout)


def rows(n, agents, m=64, seed=0):
    """Per-agent slices [A, M, ·] of a world's consecutive observations."""
    pos, vel, lm = world(n, m=m, seed=seed)
    obs = spread_obs(pos, vel, lm)
    nxt = spread_obs(pos + 0.1 * vel, vel, lm)
    act = torch.as_tensor(np.random.default_rng(seed).uniform(-1, 1, (m, n, 2)), dtype=torch.float32)
    return obs[:, agents].transpose(0, 1), act[:, agents].transpose(0, 1), nxt[:, agents].transpose(0, 1)


def test_entity_icm_trains_and_scores_every_agent():
    icm = entity_icm(4, [0, 2, 3])
    obs, act, nxt = rows(4, [0, 2, 3])
    first = icm.train_step(obs, act, nxt)
    for _ in range(40):
        last = icm.train_step(obs, act, nxt)
    assert first["inverse_loss"].shape == (3,) and last["total"] < first["total"]
    rho = icm.curiosity(obs, act, nxt)
    assert rho.shape == (3, 64) and (rho >= 0).all()


def test_entity_icm_size_depends_on_neither_n_nor_the_agent_count():
    sizes = {sum(p.numel() for p in entity_icm(n, list(range(a))).parameters()) for n, a in ((4, 4), (8, 3), (16, 16))}
    assert len(sizes) == 1


def test_curiosity_ignores_the_landmark_order():
    icm = entity_icm(3, [0, 1, 2])
    pos, vel, lm = world(3, m=16, seed=3)
    act = torch.rand(3, 16, 2)
    a = [spread_obs(pos, vel, l).transpose(0, 1) for l in (lm, lm[:, [2, 0, 1]])]
    b = [spread_obs(pos + 0.1 * vel, vel, l).transpose(0, 1) for l in (lm, lm[:, [2, 0, 1]])]
    np.testing.assert_allclose(icm.curiosity(a[0], act, b[0]), icm.curiosity(a[1], act, b[1]), atol=1e-5)


def test_entity_icm_checkpoints_and_settings():
    icm, twin = entity_icm(4, [1, 2]), entity_icm(4, [1, 2], seed=4)
    twin.load_state_dict(icm.state_dict())
    obs, act, nxt = rows(4, [1, 2], m=8)
    np.testing.assert_array_equal(twin.curiosity(obs, act, nxt), icm.curiosity(obs, act, nxt))
    layout = spread_layout(4)
    with pytest.raises(ValueError, match="icm.networks"):
        ICM(2, layout.obs_dim, 2, hidden=32).load_state_dict(icm.state_dict())
    with pytest.raises(ValueError, match="entity layout"):
        ICM(2, layout.obs_dim, 2, networks="entity")
    with pytest.raises(ValueError, match="networks"):
        ICM(2, layout.obs_dim, 2, networks="shared")

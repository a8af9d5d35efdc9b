"""MADDPG with maddpg.networks = "entity": the update, targets and checkpoints on the entity networks."""

import io

import numpy as np
import pytest
import torch

from cmcl.config import ConfigError, load_config
from cmcl.envs.entities import spread_layout
from cmcl.learners.maddpg import MADDPG
from tests.test_maddpg import joint_rows, owner_batch

torch.set_num_threads(1)

N = 4
LAYOUT = spread_layout(N)
OD = LAYOUT.obs_dim


def entity_maddpg(seed=0, **kw):
    return MADDPG(N, OD, 2, hidden=32, seed=seed, networks="entity", entity_layout=LAYOUT, **kw)


def test_update_shapes_and_the_critic_fits_a_fixed_batch():
    m = entity_maddpg(critic_lr=3e-3)
    batch = owner_batch(joint_rows(od=OD, n=N), n=N)
    before = m.critic_loss(batch)
    out = m.update(batch)
    for key in ("critic_loss", "actor_loss", "critic_grad_norm", "actor_grad_norm"):
        assert out[key].shape == (N,), key
    assert out["td_abs"].shape == (N, 32)
    np.testing.assert_allclose(out["critic_loss"], before, rtol=1e-5)
    for _ in range(40):
        m.update(batch)
    assert m.critic_loss(batch).mean() < 0.7 * before.mean()


def test_td_targets_agree_between_joint_rows_and_per_owner_rows():
    m = entity_maddpg()
    rows = joint_rows(m=20, od=OD, n=N)
    joint = m.td_targets(rows["rew"], rows["next_obs"])  # [N, M]
    per_owner = m.td_targets(np.repeat(rows["rew"][None], N, 0), np.repeat(rows["next_obs"][None], N, 0))
    # target actions are Gumbel/noise-free for tanh actors, so the two layouts must give the same numbers
    np.testing.assert_allclose(per_owner, joint, atol=1e-5)
    np.testing.assert_allclose(m.td_targets(rows["rew"], rows["next_obs"], agents=[3, 1]), joint[[3, 1]], atol=1e-6)


def test_state_dict_round_trip_and_a_per_agent_checkpoint_is_refused():
    m = entity_maddpg(seed=1)
    batch = owner_batch(joint_rows(od=OD, n=N), n=N)
    m.update(batch)
    buf = io.BytesIO()
    torch.save(m.state_dict(), buf)
    buf.seek(0)
    twin = entity_maddpg(seed=2)
    twin.load_state_dict(torch.load(buf, weights_only=True))
    obs = joint_rows(m=8, od=OD, n=N)["obs"]
    np.testing.assert_array_equal(twin.act(obs, 0.0), m.act(obs, 0.0))
    np.testing.assert_allclose(twin.update(batch)["critic_loss"], m.update(batch)["critic_loss"], rtol=1e-6)
    with pytest.raises(ValueError, match="maddpg.networks"):
        MADDPG(N, OD, 2, hidden=32).load_state_dict(m.state_dict())


def test_network_settings_are_checked():
    with pytest.raises(ValueError, match="entity layout"):
        MADDPG(N, OD, 2, networks="entity")
    with pytest.raises(ValueError, match="networks must be one of"):
        MADDPG(N, OD, 2, networks="attention")
    assert MADDPG(N, OD, 2, networks="shared").networks == "shared"
    assert load_config(None, ["maddpg.networks=entity"]).maddpg.networks == "entity"
    assert load_config(None).maddpg.networks == load_config(None).teachers.networks == "per_agent"
    with pytest.raises(ConfigError, match="maddpg.networks"):
        load_config(None, ["maddpg.networks=graph"])
    assert load_config(None, ["teachers.networks=entity"]).teachers.networks == "entity"


def test_discrete_entity_actors_update():
    m = MADDPG(N, OD, 5, hidden=32, seed=0, discrete=True, networks="entity", entity_layout=LAYOUT)
    rows = joint_rows(od=OD, n=N, ad=5)
    out = m.update(owner_batch(rows, n=N))
    assert np.isfinite(out["critic_loss"]).all() and np.isfinite(out["actor_loss"]).all()
    probs = m.act(rows["obs"][:6], 0.0)
    np.testing.assert_allclose(probs.sum(-1), 1.0, atol=1e-5)


def test_nearest_entities_are_an_opt_in_of_the_entity_learner():
    m = entity_maddpg(entity_nearest=2)
    assert m.actor.nearest == m.critic.nearest == 2 and entity_maddpg().actor.nearest == 0
    out = m.update(owner_batch(joint_rows(od=OD, n=N), n=N))
    assert np.isfinite(out["critic_loss"]).all() and np.isfinite(out["actor_loss"]).all()
    with pytest.raises(ValueError, match="nearest entities need entity networks"):
        MADDPG(N, OD, 2, entity_nearest=2)

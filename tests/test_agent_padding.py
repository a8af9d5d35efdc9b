"""Rows of fewer agents in a larger agent count's replay (run.carry_replay): the padding, the storage's agent mask, and
the learner, for which padded agents change nothing."""

import numpy as np
import pytest
import torch

from cmcl.envs.entities import spread_layout
from cmcl.learners.maddpg import MADDPG
from cmcl.replay.agent_padding import pad_rows
from cmcl.replay.buffer_steps import sample_owner_batches
from tests.buffers import make_buffer
from tests.test_maddpg import joint_rows, owner_batch

torch.set_num_threads(1)

SMALL, BIG = spread_layout(2), spread_layout(4)
S = 16


def small_rows(m=40, seed=0):
    rows = joint_rows(m=m, seed=seed, n=2, od=SMALL.obs_dim, ad=2)
    return {**rows, "done": np.zeros((m, 2), np.float32)}


def test_a_two_agent_row_keeps_its_values_in_the_four_agent_layout_and_the_rest_is_masked():
    rows = small_rows(m=3)
    out = pad_rows(rows, np.ones((3, 2), bool), SMALL, BIG)
    assert out["obs"].shape == (3, 4, BIG.obs_dim) and out["act"].shape == (3, 4, 2)
    for key in ("obs", "next_obs"):
        small, big = rows[key], out[key]
        np.testing.assert_array_equal(big[:, :2, :4], small[:, :, :4])  # own velocity and position
        np.testing.assert_array_equal(big[:, :2, 4:8], small[:, :, 4:8])  # landmarks 0 and 1
        np.testing.assert_array_equal(big[:, :2, 12:14], small[:, :, 8:10])  # the other agent: first agent slot
        assert not big[:, :2, 8:12].any() and not big[:, :2, 14:].any()  # landmarks 2, 3 and agents 2, 3: zero
        assert not big[:, 2:].any()  # absent agents' observations
    np.testing.assert_array_equal(out["act"][:, :2], rows["act"])
    np.testing.assert_array_equal(out["rew"][:, :2], rows["rew"])
    assert not out["act"][:, 2:].any() and not out["rew"][:, 2:].any()
    np.testing.assert_array_equal(out["present"], [[True, True, False, False]] * 3)
    # the entity view of a present agent: landmarks 2, 3 and agents 2, 3 are masked, the rest present
    mask = BIG.present_mask(out["present"].sum(1)[:, None].repeat(4, 1))
    np.testing.assert_array_equal(mask[0, 0], [True, True, False, False, True, False, False])
    assert BIG.present_mask(np.full((1, 4), 4)).all()


def padded_owner_batch(batch2):
    """A per-owner N = 2 batch [2, S, 2, ...] padded to N = 4: owners 0, 1 hold the same rows; owners 2, 3 hold
    rows in which they are absent (owner 0's and 1's rows again)."""
    flat = {k: v.reshape(2 * S, *v.shape[2:]) for k, v in batch2.items()}
    padded = pad_rows(flat, np.ones((2 * S, 2), bool), SMALL, BIG)
    return {k: np.concatenate([v.reshape(2, S, *v.shape[1:])] * 2) for k, v in padded.items()}


def twin_learners(seed=0, pool="attention"):
    """The same entity networks at N = 2 and at N = 4 (their parameters do not depend on N)."""
    small = MADDPG(2, SMALL.obs_dim, 2, hidden=16, seed=seed, networks="entity", entity_layout=SMALL,
                   entity_pool=pool)
    big = MADDPG(4, BIG.obs_dim, 2, hidden=16, seed=seed + 1, networks="entity", entity_layout=BIG,
                 entity_pool=pool)
    big.load_state_dict(small.state_dict())
    return small, big


@pytest.mark.parametrize("pool", ["attention", "mean", "relational"])
def test_padded_agents_change_nothing_in_the_losses_and_the_step(pool):
    small, big = twin_learners(pool=pool)
    batch2 = owner_batch(small_rows(), s=S, n=2)
    batch4 = padded_owner_batch(batch2)
    out2, out4 = small.update(batch2), big.update(batch4)
    for key in ("critic_loss", "actor_loss"):
        np.testing.assert_allclose(out4[key][:2], out2[key], rtol=1e-5, atol=1e-6)
        np.testing.assert_array_equal(out4[key][2:], 0.0)  # owners absent from every row of theirs
    np.testing.assert_allclose(out4["td_abs"][:2], out2["td_abs"], rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(out4["td_abs"][2:], 0.0)
    for part in ("actor", "critic"):  # the gradients of the step (the last backward of each network)
        for (name, a), b in zip(getattr(small, part).named_parameters(), getattr(big, part).parameters(), strict=True):
            torch.testing.assert_close(b.grad, a.grad, rtol=1e-4, atol=1e-7, msg=lambda m, n=name: f"{n}: {m}")
    if pool == "relational":  # its key bias has a zero gradient up to rounding, which Adam scales to a full step
        return
    for part in ("actor", "critic", "target_actor", "target_critic"):
        for (name, a), b in zip(getattr(small, part).state_dict().items(), getattr(big, part).state_dict().values(),
                                strict=True):
            torch.testing.assert_close(b, a, rtol=1e-5, atol=1e-6, msg=lambda m, n=f"{part}.{name}": f"{n}: {m}")


def test_without_the_mask_the_padding_changes_the_losses():
    """The control of the test above: the same padded rows read as four present agents give other losses."""
    small, big = twin_learners()
    batch2 = owner_batch(small_rows(), s=S, n=2)
    batch4 = {k: v for k, v in padded_owner_batch(batch2).items() if k != "present"}
    assert not np.allclose(big.critic_loss(batch4)[:2], small.critic_loss(batch2), rtol=1e-3)


def test_a_mixed_batch_counts_an_owner_only_on_rows_it_is_present_in():
    _, big = twin_learners()
    batch4 = padded_owner_batch(owner_batch(small_rows(), s=S, n=2))
    present = batch4["present"].copy()
    present[3, : S // 2] = True  # owner 3 present in half of its rows: four agents there
    losses = big.critic_loss({**batch4, "present": present})
    assert losses[3] > 0 and losses[2] == 0


def test_the_storage_keeps_the_agent_mask_through_a_snapshot_and_the_learner_batches_carry_it():
    replay = make_buffer(capacity=64, n_agents=4, obs_dim=BIG.obs_dim, act_dim=2, n_folds=2)
    rows = small_rows(m=8)
    padded = pad_rows(rows, np.ones((8, 2), bool), SMALL, BIG)
    replay.add(padded["obs"], padded["act"], padded["rew"], padded["next_obs"], padded["done"], np.arange(8),
               present=padded["present"])
    assert replay.storage.absent_rows == 8
    rngs = [np.random.default_rng(i) for i in range(4)]
    batch = sample_owner_batches(replay, 1, 4, rngs, [0.0] * 4)
    assert batch.minibatch(0, False)["present"].shape == (4, 4, 4)
    state = replay.state_dict()
    again = make_buffer(capacity=64, n_agents=4, obs_dim=BIG.obs_dim, act_dim=2, n_folds=2)
    again.load_state_dict(state)
    np.testing.assert_array_equal(again.storage.present[:8], padded["present"])
    assert again.storage.absent_rows == 8
    full = joint_rows(m=64, n=4, od=BIG.obs_dim, ad=2)
    again.add(full["obs"], full["act"], full["rew"], full["next_obs"], full["done"], np.arange(64))
    assert again.storage.absent_rows == 0 and "present" not in again.state_dict()["storage"]
    assert "present" not in sample_owner_batches(again, 1, 4, rngs, [0.0] * 4).rows
    with pytest.raises(ValueError, match="prefix"):
        again.add(full["obs"][:1], full["act"][:1], full["rew"][:1], full["next_obs"][:1], full["done"][:1], [0],
                  present=np.array([[True, False, True, False]]))

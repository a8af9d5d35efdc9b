"""A team's actor_batch (actor prioritised replay, Saglam et al., JAIR 2023): under "uniform" the actor
trains on a minibatch drawn uniformly from the buffer, apart from the critic's prioritised one; under "rule" (the
default) on the critic's, exactly as before. The agreement of the two runners is in tests/test_agreement.py."""

import copy

import numpy as np
import pytest
import torch

from cmcl.config import ConfigError, TeamConfig, config_from_dict, load_config
from cmcl.learners.maddpg import MADDPG
from cmcl.learners.network_steps import choose_minibatch
from cmcl.replay.agent_padding import pad_rows
from cmcl.replay.buffer_steps import sample_owner_batches
from cmcl.replay.messages import ACTOR_PREFIX
from cmcl.replay.registry import ALGORITHMS, REGISTRY
from cmcl.replay.rules.laber import select_candidates
from cmcl.system import layout_of
from tests.buffers import make_buffer
from tests.in_process import train_tiny
from tests.test_agent_padding import BIG, SMALL, small_rows, twin_learners
from tests.test_maddpg import joint_rows, owner_batch, params, same
from tests.test_replay_storage import N, filled

torch.set_num_threads(1)
UPDATE_EVERY_STEP = {"maddpg": {"update_every": 1}}  # one update per env step once warm
HOT = np.array([3, 50, 200])  # the rows the rule's priorities put (nearly) all the mass on


def states(rngs):
    return [g.bit_generator.state for g in rngs]


def hot_buffer(algorithms="per"):
    """300 rows whose every agent's priorities sit on the HOT rows (1e-12 elsewhere)."""
    rb = filled(capacity=300, episodes=10, algorithms=algorithms, alpha=1.0)
    p = np.full(rb.size, 1e-12)
    p[HOT] = 1.0
    for sampling in rb.sampling:
        sampling.set_priorities(p)
    return rb


def test_actor_batch_is_a_team_setting_acting_on_the_prioritised_rules():
    assert TeamConfig().actor_batch == "rule" and not TeamConfig(algorithm="per").uniform_actor
    for name in ALGORITHMS:
        team = TeamConfig(algorithm=name, actor_batch="uniform")
        assert team.uniform_actor == REGISTRY[name].prioritised == (name != "maddpg")  # maddpg: accepted, no effect
    assert load_config(None, ['teams.agent.algorithm="per"',
                              'teams.agent.actor_batch="uniform"']).teams["agent"].uniform_actor
    with pytest.raises(ConfigError, match="actor_batch"):
        load_config(None, ['teams.agent.actor_batch="critic"'])


def test_under_the_rule_nothing_more_is_drawn_or_carried():
    rb = hot_buffer()
    absent = [np.random.default_rng(i) for i in range(N)]
    marked_none = copy.deepcopy(absent)
    a = sample_owner_batches(rb, 2, 16, absent, [0.4] * N)  # as before the setting existed
    b = sample_owner_batches(rb, 2, 16, marked_none, [0.4] * N, 1, (False,) * N)
    assert a.actor is None and b.actor is None and states(absent) == states(marked_none)
    np.testing.assert_array_equal(a.slots, b.slots)
    np.testing.assert_array_equal(a.is_weights, b.is_weights)
    minibatch, _, _ = choose_minibatch(None, b, 0, True, (False,) * N)
    assert not any(k.startswith(ACTOR_PREFIX) for k in minibatch)


def test_the_actor_rows_cover_the_buffer_while_the_critic_rows_follow_the_rule():
    rb = hot_buffer()
    rngs = [np.random.default_rng(i) for i in range(N)]
    batch = sample_owner_batches(rb, 40, 16, rngs, [0.4] * N, 1, (True,) * N)
    assert np.isin(batch.slots, HOT).all()  # the critic: the rule's rows only
    actor = batch.actor.slots
    assert actor.shape == batch.slots.shape and batch.actor.owners.all()
    for agent in range(N):
        seen = np.unique(actor[:, agent])  # 640 uniform draws of 300 rows: ~88% of them expected
        assert seen.size > 0.8 * rb.size and np.isin(actor[:, agent], HOT).mean() < 0.05
    counts = np.bincount(actor.ravel(), minlength=rb.size)
    assert counts.max() < 20  # no row is favoured (the mean is 6.4)
    rows = rb.get(actor.reshape(-1))
    for key in ("obs", "act"):
        np.testing.assert_array_equal(batch.actor.rows[key], rows[key].reshape(*actor.shape, *rows[key].shape[1:]))
    assert set(batch.actor.rows) == {"obs", "act"}  # the actor step reads no more
    minibatch, slots, _ = choose_minibatch(None, batch, 0, True, (False,) * N)
    np.testing.assert_array_equal(slots, batch.slots[0])  # the feedback is about the critic's rows
    np.testing.assert_array_equal(minibatch["actor_obs"], batch.actor.rows["obs"][0])
    assert "is_weights" in minibatch and "actor_is_weights" not in minibatch


def test_only_the_marked_owners_draw_more_and_the_others_actor_takes_its_critic_rows():
    rb = hot_buffer()
    rngs = [np.random.default_rng(i) for i in range(N)]
    plain = copy.deepcopy(rngs)
    marked = (True,) + (False,) * (N - 1)
    batch = sample_owner_batches(rb, 3, 16, rngs, [0.4] * N, 1, marked)
    sample_owner_batches(rb, 3, 16, plain, [0.4] * N)
    assert states(rngs)[1:] == states(plain)[1:] and states(rngs)[0] != states(plain)[0]
    np.testing.assert_array_equal(batch.actor.slots[:, 1:], batch.slots[:, 1:])
    minibatch, _, _ = choose_minibatch(None, batch, 1, False, (False,) * N)
    np.testing.assert_array_equal(minibatch["actor_obs"][0], batch.actor.rows["obs"][1, 0])
    np.testing.assert_array_equal(minibatch["actor_obs"][1:], minibatch["obs"][1:])


def test_a_laber_owner_whose_actor_follows_the_rule_trains_it_on_its_picked_rows():
    rb = filled(capacity=300, episodes=10, algorithms=["laber", "laber", "per"])
    rngs = [np.random.default_rng(i) for i in range(N)]
    batch = sample_owner_batches(rb, 1, 8, rngs, [0.0] * N, 4, (True, False, True))
    assert batch.slots.shape == (1, N, 32) and batch.actor.slots.shape == (1, N, 8)
    maddpg = MADDPG(N, rb.storage.obs_dim, rb.storage.act_dim, hidden=16, seed=0)
    minibatch, slots, _ = choose_minibatch(maddpg, batch, 0, True, (True, True, False), select_candidates)
    np.testing.assert_array_equal(minibatch["actor_obs"][[0, 2]], batch.actor.rows["obs"][0, [0, 2]])
    np.testing.assert_array_equal(minibatch["actor_obs"][1], minibatch["obs"][1])  # the pick, not the candidates
    np.testing.assert_array_equal(minibatch["obs"][1], rb.get(slots[1])["obs"])


def test_carried_rows_give_the_actor_rows_their_agents_presence():
    replay = make_buffer(capacity=64, n_agents=4, obs_dim=BIG.obs_dim, act_dim=2, n_folds=2, algorithms="per")
    padded = pad_rows(small_rows(m=8), np.ones((8, 2), bool), SMALL, BIG)
    replay.add(padded["obs"], padded["act"], padded["rew"], padded["next_obs"], padded["done"], np.arange(8),
               present=padded["present"])
    full = joint_rows(m=24, n=4, od=BIG.obs_dim, ad=2)
    replay.add(full["obs"], full["act"], full["rew"], full["next_obs"], full["done"], np.arange(8, 32))
    batch = sample_owner_batches(replay, 1, 16, [np.random.default_rng(i) for i in range(4)], [0.4] * 4, 1,
                                 (True,) * 4)
    present = replay.storage.present[batch.actor.slots]
    np.testing.assert_array_equal(batch.actor.rows["present"], present)
    minibatch, _, _ = choose_minibatch(None, batch, 0, True, (False,) * 4)
    assert minibatch["actor_present"].shape == (4, 16, 4) and not present.all()
    _, big = twin_learners()
    out = big.update(minibatch)
    assert np.isfinite(out["actor_loss"]).all() and np.isfinite(out["critic_loss"]).all()


def test_the_critic_steps_on_its_batch_and_the_actor_on_its_own():
    rows = joint_rows()
    batch, other = owner_batch(rows, seed=1), owner_batch(rows, seed=2)
    base = MADDPG(3, 6, 2, hidden=32, seed=0)
    plain, same_rows, own_rows = (copy.deepcopy(base) for _ in range(3))
    out = plain.update(batch)
    echo = same_rows.update({**batch, "actor_obs": batch["obs"], "actor_act": batch["act"]})
    own = own_rows.update({**batch, "actor_obs": other["obs"], "actor_act": other["act"]})
    for key in out:  # the critic's own rows given as the actor's: bit-identical to no actor rows
        np.testing.assert_array_equal(echo[key], out[key])
    assert same(params(same_rows.actor), params(plain.actor)) and same(params(same_rows.critic), params(plain.critic))
    for key in ("critic_loss", "td_abs", "critic_grad_norm"):  # the critic did not see the actor's rows
        np.testing.assert_array_equal(own[key], out[key])
    assert same(params(own_rows.critic), params(plain.critic))
    assert not np.array_equal(own["actor_loss"], out["actor_loss"]) and not same(params(own_rows.actor),
                                                                                 params(plain.actor))
    with pytest.raises(ValueError, match="actor_obs"):
        copy.deepcopy(base).update({**batch, "actor_obs": other["obs"][:, :, :2], "actor_act": other["act"]})


def with_actor_batch(config, value):
    data = config.to_dict()
    for team in data["teams"].values():
        team["actor_batch"] = value
    # β_IS anneals over run.episodes, which differs between a split run's parts: held fixed for the comparison
    data["replay"]["beta_is_start"] = data["replay"]["beta_is_end"]
    return config_from_dict(data)


def weights(roles):
    return {part: copy.deepcopy(getattr(roles.learner.maddpg, part).state_dict()) for part in ("actor", "critic")}


def assert_same_weights(a, b):
    for part in a:
        for key, value in a[part].items():
            torch.testing.assert_close(b[part][key], value, rtol=0, atol=0)


def counters(summary):
    return {k: summary[k] for k in ("episodes", "env_steps", "updates")}


def test_an_inline_run_with_uniform_actor_rows_resumes_and_trains_other_actors_than_the_rule(tmp_path, tiny_config):
    config = with_actor_batch(tiny_config("per", service=True, sections=UPDATE_EVERY_STEP), "uniform")
    assert all(layout_of(config).uniform_actor)
    full, full_roles = train_tiny(config, tmp_path / "full", 8)
    split, _ = train_tiny(config, tmp_path / "split", 4)
    resumed, resumed_roles = train_tiny(config, tmp_path / "split", 8, resume=True)
    # the service's checkpoints restart the worlds (not bit-exact): the resumed run goes on from the first part
    assert counters(resumed) == counters(full) and split["updates"] < resumed["updates"] and full["updates"] > 0
    assert resumed_roles.learner.maddpg.updates == resumed["updates"]
    rule, rule_roles = train_tiny(with_actor_batch(config, "rule"), tmp_path / "rule", 8)
    assert counters(rule) == counters(full)
    with pytest.raises(AssertionError):  # the actor trained on other rows
        assert_same_weights(weights(full_roles), weights(rule_roles))


def test_uniform_actor_rows_under_maddpg_train_exactly_as_the_rule(tmp_path, tiny_config):
    config = tiny_config("maddpg", service=True, sections=UPDATE_EVERY_STEP)
    _, default = train_tiny(config, tmp_path / "default", 6)
    _, uniform = train_tiny(with_actor_batch(config, "uniform"), tmp_path / "uniform", 6)
    assert not any(uniform.learner.layout.uniform_actor) and uniform.learner.layout.uniform_actor
    assert_same_weights(weights(default), weights(uniform))

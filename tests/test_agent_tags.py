"""Per-episode agent tags of the navigation task (SpreadParams.agent_tags): the observation's N extra columns in both
implementations, the entity layout that reads them, the entity networks and their numpy twin on tagged rows, and
a short training run with tags."""

import json

import numpy as np
import pytest
import torch

from cmcl.envs import sparse_spread_v0
from cmcl.envs.batched import BatchedSparseSpread
from cmcl.envs.entities import ABSENT, entity_layout, spread_layout
from cmcl.envs.params import SpreadParams
from cmcl.envs.state import get_world_state, set_world_state
from cmcl.learners.entity.nets import EntityActor, EntityCritic
from cmcl.learners.nets import joint_input
from cmcl.replay.agent_padding import pad_rows

torch.set_num_threads(1)


def _tags_of(obs: np.ndarray, n: int) -> np.ndarray:
    """The tag columns of obs [..., N, obs_dim] -> [..., N, N]: row i = [u_i, u_j for j != i]."""
    return obs[..., -n:]


def _expected(tags: np.ndarray) -> np.ndarray:
    """tags [..., N] -> [..., N, N], row i = [u_i, u_j for j != i in index order]."""
    n = tags.shape[-1]
    return np.stack([np.concatenate([tags[..., i : i + 1], np.delete(tags, i, -1)], -1) for i in range(n)], -2)


@pytest.mark.parametrize("n", [1, 3, 8])
def test_obs_width_and_the_untagged_prefix(n):
    params = SpreadParams(num_agents=n, agent_tags=True)
    assert params.obs_dim == 4 + 2 * n + 2 * (n - 1) + n == SpreadParams(num_agents=n).obs_dim + n
    twin = BatchedSparseSpread(3, params, seed=4)
    plain = BatchedSparseSpread(3, SpreadParams(num_agents=n), seed=4)
    obs, ref = twin.observe(), plain.observe()  # the first episodes, drawn by the constructors
    assert obs.shape == (3, n, params.obs_dim)
    np.testing.assert_array_equal(obs[..., : ref.shape[-1]], ref)  # tags are drawn after the initial state
    env = sparse_spread_v0.parallel_env(num_agents=n, agent_tags=True)
    assert all(env.observation_space(a).shape == (params.obs_dim,) for a in env.possible_agents)
    pz_obs, _ = env.reset(seed=2)
    assert all(o.shape == (params.obs_dim,) for o in pz_obs.values())


def test_tags_are_fixed_through_an_episode_redrawn_at_reset_and_listed_in_index_order():
    n, b = 4, 5
    twin = BatchedSparseSpread(b, SpreadParams(num_agents=n, agent_tags=True), seed=1, auto_reset=True,
                               episode_length=6)
    rng = np.random.default_rng(0)
    obs = twin.reset()
    tags = twin.get_state()["tags"]  # [B, N]
    assert tags.shape == (b, n) and ((tags >= 0) & (tags < 1)).all()
    assert all(len(set(row)) == n for row in tags)  # distinct within a world
    assert not np.allclose(tags[0], tags[1])  # independent per world
    np.testing.assert_array_equal(_tags_of(obs, n), _expected(tags))
    for _ in range(6):
        obs, _, dones, info = twin.step(rng.uniform(-1, 1, (b, n, 2)))
        np.testing.assert_array_equal(_tags_of(info["final_obs"], n), _expected(tags))  # the episode's tags
    assert dones.all()
    fresh = twin.get_state()["tags"]
    assert not np.isin(fresh, tags).any()  # the next episodes drew new ones
    np.testing.assert_array_equal(_tags_of(obs, n), _expected(fresh))
    # the PettingZoo env: constant within an episode, new at reset
    env = sparse_spread_v0.parallel_env(num_agents=n, agent_tags=True, max_cycles=5)
    first, _ = env.reset(seed=3)
    u = env.unwrapped.tags.copy()
    for i, a in enumerate(env.possible_agents):
        np.testing.assert_array_equal(first[a][-n:], _expected(u)[i].astype(np.float32))
    while env.agents:
        out, *_ = env.step({a: np.ones(2, np.float32) for a in env.agents})
        for a in out:
            np.testing.assert_array_equal(out[a][-n:], first[a][-n:])
    second, _ = env.reset()
    assert not np.isin(env.unwrapped.tags, u).any()
    assert not np.array_equal(second["agent_0"][-n:], first["agent_0"][-n:])


def test_same_seed_gives_the_same_tags_in_both_implementations_and_the_state_carries_them():
    params = SpreadParams(num_agents=3, agent_tags=True)
    env = sparse_spread_v0.parallel_env(num_agents=3, agent_tags=True)
    obs, _ = env.reset(seed=11)
    twin = BatchedSparseSpread(1, params, seed=11, dtype=np.float64)
    np.testing.assert_array_equal(twin.get_state()["tags"], get_world_state(env)["tags"])
    for i, a in enumerate(env.possible_agents):
        np.testing.assert_allclose(twin.observe()[0, i], obs[a], atol=1e-6)
    other = sparse_spread_v0.parallel_env(num_agents=3, agent_tags=True)
    other.reset(seed=99)
    back = set_world_state(other, twin.get_state())
    for a in env.possible_agents:
        np.testing.assert_array_equal(back[a], obs[a])
    state = twin.get_state()
    del state["tags"]
    with pytest.raises(ValueError, match="tags"):
        twin.set_state(state)
    with pytest.raises(ValueError, match="unknown keys"):  # a tagged state into an untagged world
        BatchedSparseSpread(1, SpreadParams(num_agents=3)).set_state(twin.get_state())


def test_default_off_is_the_untagged_world_unchanged():
    assert SpreadParams().agent_tags is False and SpreadParams().obs_dim == 18
    twin = BatchedSparseSpread(2, SpreadParams(), seed=5)
    assert "tags" not in twin.get_state() and twin.obs_dim == 18
    env = sparse_spread_v0.parallel_env()
    env.reset(seed=5)
    assert env.unwrapped.tags is None and "tags" not in get_world_state(env)
    assert spread_layout(4).own_dim == 4 and spread_layout(4).entity_dim == 4


@pytest.mark.parametrize("n", [2, 5])
def test_tagged_layout_splits_own_tag_and_the_other_agents_tags(n):
    params = SpreadParams(num_agents=n, agent_tags=True)
    layout = entity_layout(params)
    assert layout.obs_dim == params.obs_dim and layout.own_dim == 5 and layout.entity_dim == 5
    assert layout.num_entities == 2 * n - 1
    twin = BatchedSparseSpread(3, params, seed=2)
    obs = twin.step(np.random.default_rng(0).uniform(-1, 1, (3, n, 2)))[0]
    own, ents, mask = layout.split(obs)
    tags = twin.get_state()["tags"]  # [B, N]
    pos = twin.get_state()["positions"]
    np.testing.assert_array_equal(own[..., 4], tags)
    assert (ents[:, :, :n, 2] == 0).all() and (layout.entity_index[:, :n, 2] == ABSENT).all()  # landmarks
    for i in range(n):
        others = [j for j in range(n) if j != i]
        np.testing.assert_array_equal(ents[:, i, n:, 2], tags[:, others])
        np.testing.assert_allclose(ents[:, i, n:, :2], pos[:, others] - pos[:, i : i + 1], atol=1e-6)
        assert layout.entity_agent[i, n:].tolist() == others
        cols = np.concatenate([layout.own_index[i], layout.entity_index[i].ravel()])
        assert sorted(cols[cols != ABSENT].tolist()) == list(range(layout.obs_dim))  # every column once
    assert (ents[..., :n, 3] == 1).all() and (ents[..., n:, 4] == 1).all() and mask.all()


def _tagged_nets(n, hidden=16, seed=0, pool="attention"):
    gen = torch.Generator().manual_seed(seed)
    layout = spread_layout(n, agent_tags=True)
    return layout, EntityActor(layout, 2, hidden, gen, out_act=torch.nn.Tanh, pool=pool), \
        EntityCritic(layout, 2, hidden, gen, pool=pool)


def _tagged_obs(n, m=6, seed=0):
    twin = BatchedSparseSpread(m, SpreadParams(num_agents=n, agent_tags=True), seed=seed)
    obs = twin.step(np.random.default_rng(seed).uniform(-1, 1, (m, n, 2)))[0]
    return torch.as_tensor(obs), twin


def test_entity_networks_read_the_tags_and_keep_their_size_for_any_n():
    sizes = {n: tuple(sum(p.numel() for p in m.parameters()) for m in _tagged_nets(n)[1:]) for n in (3, 8)}
    assert sizes[3] == sizes[8]
    n = 4
    _, actor, critic = _tagged_nets(n)
    obs, _ = _tagged_obs(n)
    act = torch.rand(obs.shape[0], n, 2) * 2 - 1
    out, q = actor(obs.transpose(0, 1)), critic(joint_input(obs, act))[..., 0]
    assert out.shape == (n, obs.shape[0], 2) and q.shape == (n, obs.shape[0])
    retagged = obs.clone()
    retagged[..., -n:] = torch.rand(n).expand(obs.shape[0], n, n)  # other tags, the same world
    assert not torch.allclose(actor(retagged.transpose(0, 1)), out, atol=1e-5)
    assert not torch.allclose(critic(joint_input(retagged, act))[..., 0], q, atol=1e-5)
    # permuting the agents (their tags with them) permutes the critic's Q's
    pos, vel, lm, tags = (np.asarray(v, np.float64) for v in (np.random.default_rng(1).uniform(-.4, .4, (5, n, 2)),
                          np.random.default_rng(2).normal(0, .3, (5, n, 2)),
                          np.random.default_rng(3).uniform(-.4, .4, (5, n, 2)),
                          np.random.default_rng(4).uniform(0, 1, (5, n))))

    def flat(p, v, u):
        twin = BatchedSparseSpread(5, SpreadParams(num_agents=n, agent_tags=True), dtype=np.float64)
        return torch.as_tensor(twin.set_state({"positions": p, "velocities": v, "landmarks": lm,
                                               "step": np.zeros(5, np.int64), "tags": u}), dtype=torch.float32)

    a = torch.rand(5, n, 2) * 2 - 1
    perm = [2, 0, 3, 1]
    q0 = critic(joint_input(flat(pos, vel, tags), a))[..., 0]
    q1 = critic(joint_input(flat(pos[:, perm], vel[:, perm], tags[:, perm]), a[:, perm]))[..., 0]
    torch.testing.assert_close(q1, q0[perm], atol=1e-5, rtol=1e-5)
    # the actor step's shortcut gives the joint path's values and gradients with S = 5 and P = 3
    s = 7
    gen = torch.Generator().manual_seed(5)
    o = torch.randn(n, s, n, critic.obs_dim, generator=gen)
    acts = torch.rand(n, s, n, 2, generator=gen) * 2 - 1
    own_a = (torch.rand(n, s, 2, generator=gen) * 2 - 1).requires_grad_()
    own_b = own_a.detach().clone().requires_grad_()
    joint = torch.where(torch.eye(n, dtype=torch.bool).view(n, 1, n, 1), own_a.unsqueeze(2), acts)
    q_joint = critic(joint_input(o, joint))[..., 0]
    q_own = critic.q_own_action(o, acts, own_b)
    torch.testing.assert_close(q_own, q_joint, atol=1e-6, rtol=1e-6)
    q_joint.sum().backward()
    q_own.sum().backward()
    torch.testing.assert_close(own_b.grad, own_a.grad, atol=1e-6, rtol=1e-6)


@pytest.mark.parametrize("pool", ["attention", "mean", "relational"])
def test_numpy_entity_policy_matches_the_torch_actor_on_tagged_observations(pool):
    from cmcl.learners.maddpg import MADDPG
    from cmcl.learners.weights import published_weights
    from cmcl.rollout.policy import NumpyEntityPolicy, numpy_policy

    n = 5
    layout = spread_layout(n, agent_tags=True)
    maddpg = MADDPG(n, layout.obs_dim, seed=3, networks="entity", entity_layout=layout, entity_pool=pool)
    obs = _tagged_obs(n, m=16)[0].numpy()
    policy = numpy_policy(published_weights(maddpg)["actor"], entities=layout)
    assert isinstance(policy, NumpyEntityPolicy)
    for noise in (0.0, 0.1):
        ours = policy.act(obs, noise, rng=np.random.default_rng(7))
        theirs = maddpg.act(obs, noise, rng=np.random.default_rng(7))
        np.testing.assert_allclose(ours, theirs, atol=1e-5)


def test_padding_carries_tagged_rows_to_more_agents():
    small, big = spread_layout(2, agent_tags=True), spread_layout(4, agent_tags=True)
    obs = _tagged_obs(2, m=3)[0].numpy()
    rows = {"obs": obs, "next_obs": obs, "act": np.zeros((3, 2, 2)), "rew": np.zeros((3, 2)), "done": np.zeros((3, 2))}
    padded = pad_rows(rows, np.ones((3, 2), bool), small, big)
    own_s, ents_s, _ = small.split(obs)
    own_b, ents_b, _ = big.split(padded["obs"])
    np.testing.assert_array_equal(own_b[:, :2], own_s)  # own tags kept
    np.testing.assert_array_equal(ents_b[:, 0, 4, 2], ents_s[:, 0, 2, 2])  # agent 0's view of agent 1: its tag
    with pytest.raises(ValueError, match="do not fit"):
        pad_rows(rows, np.ones((3, 2), bool), small, spread_layout(4))


def test_a_short_tagged_training_run_and_its_evaluation(tmp_path, capsys):
    from cmcl.__main__ import main as cmcl
    from cmcl.run.evaluate import main as evaluate

    run = tmp_path / "run"
    assert cmcl(["train", "--runner", "inline", "--config", "configs/smoke.toml", "--set", f"run.dir={run}",
                 "--set", "run.episodes=8", "--set", "env.num_agents=3", "--set", "env.agent_tags=true",
                 "--set", "maddpg.networks=entity", "--set", "maddpg.warmup=64", "--set", "maddpg.batch_size=16",
                 "--quiet"]) == 0
    capsys.readouterr()
    assert "agent_tags = true" in (run / "config.toml").read_text()
    assert evaluate([str(run), "--episodes", "8", "--gif", str(tmp_path / "e.gif")]) == 0
    text = capsys.readouterr().out
    result = json.loads(text[: text.index("gif:")])
    assert result["policy"] == "trained" and 0.0 <= result["coverage"] <= 1.0

"""MADDPG (ALGORITHM.md §2): critic/actor steps, targets, |delta|, weights shipping, state round trip."""

import copy
import io

import numpy as np
import pytest
import torch

from cmcl.learners.maddpg import MADDPG
from cmcl.learners.nets import joint_input
from cmcl.scorers.icm import ICM

torch.set_num_threads(1)

N, OD, AD, S = 3, 6, 2, 32


def joint_rows(m=200, seed=0, n=N, od=OD, ad=AD):
    """Random joint transitions: obs [M,N,od], act [M,N,ad], rew [M,N], next_obs, done [M]."""
    rng = np.random.default_rng(seed)
    return {
        "obs": rng.normal(size=(m, n, od)).astype(np.float32),
        "act": rng.uniform(-1, 1, size=(m, n, ad)).astype(np.float32),
        "rew": rng.normal(size=(m, n)).astype(np.float32),
        "next_obs": rng.normal(size=(m, n, od)).astype(np.float32),
        "done": np.zeros(m, np.float32),
    }


def owner_batch(rows, s=S, seed=1, n=N):
    """Per-owner minibatch: every agent draws its own index set -> leading owner axis [N, S, ...]."""
    idx = np.random.default_rng(seed).integers(0, rows["obs"].shape[0], size=(n, s))
    return {k: v[idx] for k, v in rows.items()}


def params(module):
    return [p.detach().clone() for p in module.parameters()]


def same(a, b):
    return all(torch.equal(x, y) for x, y in zip(a, b, strict=True))


def test_update_lowers_critic_loss_on_fixed_batch():
    m = MADDPG(N, OD, AD, seed=0)
    batch = owner_batch(joint_rows())
    before = m.critic_loss(batch)
    out = m.update(batch)
    after = m.critic_loss(batch)
    np.testing.assert_allclose(out["critic_loss"], before, rtol=1e-5)
    assert (after < before).all(), (before, after)
    for _ in range(20):
        m.update(batch)
    assert (m.critic_loss(batch) < 0.9 * before).all()


def test_update_output_shapes_and_td_abs():
    m = MADDPG(N, OD, AD, seed=0)
    batch = owner_batch(joint_rows())
    y = m.td_targets(batch["rew"], batch["next_obs"], batch["done"])
    q = m.critic(joint_input(torch.as_tensor(batch["obs"]), torch.as_tensor(batch["act"]))).squeeze(-1)
    out = m.update(batch)
    assert out["td_abs"].shape == (N, S) and out["td_abs"].dtype == np.float32
    np.testing.assert_allclose(out["td_abs"], np.abs(y - q.detach().numpy()), rtol=1e-5, atol=1e-6)
    for k in ("critic_loss", "actor_loss", "critic_grad_norm", "actor_grad_norm"):
        assert out[k].shape == (N,)


def test_is_weights_weight_the_critic_loss():
    m = MADDPG(N, OD, AD, seed=0)
    batch = owner_batch(joint_rows())
    plain = m.critic_loss(batch)
    w = np.zeros((N, S), np.float32)
    w[:, 0] = 1.0
    weighted = m.critic_loss({**batch, "is_weights": w})
    out = m.update({**batch, "is_weights": w})
    np.testing.assert_allclose(weighted, out["td_abs"][:, 0] ** 2 / S, rtol=1e-4)
    assert not np.allclose(weighted, plain)


def test_actor_step_changes_only_actors_and_critic_step_only_critics():
    m = MADDPG(N, OD, AD, seed=0)
    batch = owner_batch(joint_rows())
    obs, act = torch.as_tensor(batch["obs"]), torch.as_tensor(batch["act"])
    a0, c0 = params(m.actor), params(m.critic)
    m._actor_step(obs, act)
    assert same(params(m.critic), c0) and not same(params(m.actor), a0)
    a1 = params(m.actor)
    tensors = [torch.as_tensor(batch[k]) for k in ("obs", "act", "rew", "next_obs", "done")]
    m._critic_step(*tensors, None)
    assert same(params(m.actor), a1) and not same(params(m.critic), c0)


def test_actor_gradient_per_agent_uses_only_own_action_slot():
    """Agent v's actor loss depends on pi_v only: zeroing other agents' actor grads changes nothing."""
    m = MADDPG(N, OD, AD, seed=0)
    batch = owner_batch(joint_rows())
    obs, act = torch.as_tensor(batch["obs"]), torch.as_tensor(batch["act"])
    own = obs[torch.arange(N), :, torch.arange(N)]
    pi = m.actor(own)
    joint = torch.where(m._own_mask, pi.unsqueeze(2), act)
    # owner 1's joint action: slot 1 replaced, slots 0 and 2 from the buffer
    torch.testing.assert_close(joint[1, :, 0], act[1, :, 0])
    torch.testing.assert_close(joint[1, :, 1], pi[1])
    loss1 = -m.critic(joint_input(obs, joint))[1].mean()
    grads = torch.autograd.grad(loss1, list(m.actor.parameters()))
    for g in grads:
        assert g[0].abs().max() == 0 and g[2].abs().max() == 0 and g[1].abs().max() > 0


def test_target_soft_update_is_exact_tau():
    m = MADDPG(N, OD, AD, tau=0.01, seed=0)
    # make targets differ from the online nets so the interpolation is visible
    with torch.no_grad():
        for p in m.target_critic.parameters():
            p.add_(1.0)
    batch = owner_batch(joint_rows())
    tc0, ta0 = params(m.target_critic), params(m.target_actor)
    m.update(batch)
    for t, t0, s in zip(m.target_critic.parameters(), tc0, m.critic.parameters(), strict=True):
        torch.testing.assert_close(t, 0.01 * s + 0.99 * t0, rtol=0, atol=1e-6)
    for t, t0, s in zip(m.target_actor.parameters(), ta0, m.actor.parameters(), strict=True):
        torch.testing.assert_close(t, 0.01 * s + 0.99 * t0, rtol=0, atol=1e-6)


def test_td_targets_use_target_nets_and_next_obs():
    m = MADDPG(N, OD, AD, gamma=0.9, seed=0)
    rows = joint_rows(50)
    y = m.td_targets(rows["rew"], rows["next_obs"], rows["done"])
    assert y.shape == (N, 50)
    with torch.no_grad():  # online nets changed: y unchanged
        for p in [*m.critic.parameters(), *m.actor.parameters()]:
            p.add_(0.3)
    np.testing.assert_array_equal(m.td_targets(rows["rew"], rows["next_obs"], rows["done"]), y)
    # explicit formula with target nets on NEXT obs
    no = torch.as_tensor(rows["next_obs"])
    a2 = m.target_actor(no.transpose(0, 1)).transpose(0, 1)
    q2 = m.target_critic(joint_input(no, a2)).squeeze(-1)
    np.testing.assert_allclose(y, rows["rew"].T + 0.9 * q2.detach().numpy(), rtol=1e-5, atol=1e-5)
    # obs (current) is not an input; next_obs is
    rows2 = {**rows, "next_obs": rows["next_obs"] + 1.0}
    assert not np.allclose(m.td_targets(rows2["rew"], rows2["next_obs"]), y)
    # done = 1 removes the bootstrap; agent subset selects rows
    np.testing.assert_allclose(m.td_targets(rows["rew"], rows["next_obs"], np.ones(50, np.float32)), rows["rew"].T)
    np.testing.assert_allclose(m.td_targets(rows["rew"], rows["next_obs"], agents=[2, 0]), y[[2, 0]], rtol=1e-6)


def test_td_targets_per_owner_matches_joint_rows():
    m = MADDPG(N, OD, AD, seed=0)
    rows = joint_rows(80)
    idx = np.random.default_rng(3).integers(0, 80, size=(N, 10))
    y_joint = m.td_targets(rows["rew"], rows["next_obs"])  # [N, 80]
    y_owner = m.td_targets(rows["rew"][idx], rows["next_obs"][idx])  # [N, 10]
    np.testing.assert_allclose(y_owner, np.take_along_axis(y_joint, idx, axis=1), rtol=1e-5, atol=1e-5)
    y_sub = m.td_targets(rows["rew"][idx[:2]], rows["next_obs"][idx[:2]], agents=[1, 2])
    np.testing.assert_allclose(y_sub, np.take_along_axis(y_joint[[1, 2]], idx[:2], axis=1), rtol=1e-5, atol=1e-5)


def test_act_shapes_clipping_and_determinism():
    m = MADDPG(N, OD, AD, seed=0)
    obs = joint_rows(20)["obs"]
    a = m.act(obs, noise_std=0.0)
    assert a.shape == (20, N, AD) and a.dtype == np.float32
    big = m.act(obs, noise_std=10.0, rng=np.random.default_rng(0))
    assert np.abs(big).max() <= 1.0 and (np.abs(big) == 1.0).any()
    np.testing.assert_array_equal(big, m.act(obs, noise_std=10.0, rng=np.random.default_rng(0)))


def test_state_dict_round_trip_through_torch_save():
    m = MADDPG(N, OD, AD, seed=0)
    batch = owner_batch(joint_rows())
    for _ in range(3):
        m.update(batch)
    buf = io.BytesIO()
    torch.save(m.state_dict(), buf)
    buf.seek(0)
    state = torch.load(buf, weights_only=True)
    m2 = MADDPG(N, OD, AD, seed=123)
    m2.load_state_dict(state)
    obs = joint_rows(10)["obs"]
    np.testing.assert_array_equal(m2.act(obs, noise_std=0.1), m.act(obs, noise_std=0.1))
    out1, out2 = m.update(batch), m2.update(batch)  # optimiser state restored too: identical next step
    for k in out1:
        np.testing.assert_array_equal(out1[k], out2[k])
    assert m2.updates == m.updates == 4


def test_actor_weights_ship_to_a_worker():
    m = MADDPG(N, OD, AD, seed=0)
    m.update(owner_batch(joint_rows()))
    w = m.actor_weights()
    assert all(isinstance(v, np.ndarray) for v in w.values())
    assert w["layers.0.weight"].shape == (N, OD, 64)
    worker = MADDPG(N, OD, AD, seed=9)
    worker.load_actor_weights(w)
    obs = joint_rows(10)["obs"]
    np.testing.assert_array_equal(worker.act(obs, 0.0), m.act(obs, 0.0))
    bad = {**w, "layers.0.weight": np.full_like(w["layers.0.weight"], np.nan)}
    with pytest.raises(ValueError):
        worker.load_actor_weights(bad)


def test_discrete_gumbel_variant_updates():
    m = MADDPG(N, OD, 5, discrete=True, seed=0)
    rows = joint_rows(ad=5)
    rows["act"] = np.eye(5, dtype=np.float32)[np.random.default_rng(0).integers(0, 5, size=(200, N))]
    a = m.act(rows["obs"][:7], rng=np.random.default_rng(1))
    assert a.shape == (7, N, 5)
    np.testing.assert_allclose(a.sum(-1), 1.0, rtol=1e-5)
    batch = owner_batch(rows)
    before = m.critic_loss(batch)
    out = m.update(batch)
    assert np.isfinite(out["actor_loss"]).all() and (m.critic_loss(batch) < before).all()


def test_icm_and_maddpg_do_not_touch_each_other():
    """Property 26: ICM steps leave actor/critic params unchanged and MADDPG steps leave ICM params unchanged."""
    m = MADDPG(N, OD, AD, seed=0)
    icm = ICM(N, OD, AD, seed=0)
    rows = joint_rows()
    batch = owner_batch(rows)
    nets = [m.actor, m.critic, m.target_actor, m.target_critic]
    snap = [params(n) for n in nets]
    per_agent = {k: torch.as_tensor(rows[k][:64]).transpose(0, 1) for k in ("obs", "act", "next_obs")}
    icm.train_step(per_agent["obs"], per_agent["act"], per_agent["next_obs"])
    assert all(same(params(n), s) for n, s in zip(nets, snap, strict=True))
    icm_snap = [p.detach().clone() for p in icm.parameters()]
    m.update(batch)
    assert same([p.detach() for p in icm.parameters()], icm_snap)
    assert not same(params(m.critic), snap[1])


def test_deepcopy_independent():
    m = MADDPG(N, OD, AD, seed=0)
    m2 = copy.deepcopy(m)
    m.update(owner_batch(joint_rows()))
    assert not same(params(m.actor), params(m2.actor))


def test_actors_learn_a_one_step_bandit():
    """gamma = 0, r_v = -||a_v - target||^2 from random buffer actions: deterministic actions approach the target."""
    rng = np.random.default_rng(0)
    m_rows, target = 2000, np.array([0.5, -0.3], np.float32)
    obs = rng.normal(size=(m_rows, 2, 4)).astype(np.float32)
    act = rng.uniform(-1, 1, size=(m_rows, 2, 2)).astype(np.float32)
    rows = {"obs": obs, "act": act, "rew": -((act - target) ** 2).sum(-1), "next_obs": obs}
    m = MADDPG(2, 4, 2, gamma=0.0, actor_lr=1e-3, critic_lr=1e-2, seed=0)
    d0 = np.abs(m.act(obs[:200], noise_std=0) - target).mean()
    for _ in range(300):
        idx = rng.integers(0, m_rows, size=(2, 64))
        m.update({k: v[idx] for k, v in rows.items()})
    d1 = np.abs(m.act(obs[:200], noise_std=0) - target).mean()
    assert d1 < 0.5 * d0, (d0, d1)


def test_shared_parameters_tell_agents_apart_by_their_own_bias():
    """One shared actor and critic for 3 agents whose observations are identical but whose best actions differ
    (γ = 0, r_v = −||a_v − target_v||²): only the per-agent first-layer bias can separate them, and it does."""
    rng = np.random.default_rng(0)
    targets = np.array([[0.5, -0.3], [-0.5, 0.3], [0.0, 0.6]], np.float32)
    m_rows = 2000
    obs = np.repeat(rng.normal(size=(m_rows, 1, 4)).astype(np.float32), 3, axis=1)  # every agent sees the same
    act = rng.uniform(-1, 1, size=(m_rows, 3, 2)).astype(np.float32)
    rows = {"obs": obs, "act": act, "rew": -((act - targets) ** 2).sum(-1), "next_obs": obs}
    m = MADDPG(3, 4, 2, gamma=0.0, actor_lr=1e-3, critic_lr=1e-2, seed=0, networks="shared")
    assert sum(p.numel() for p in m.actor.parameters()) < sum(p.numel() for p in MADDPG(3, 4, 2).actor.parameters())
    d0 = np.abs(m.act(obs[:200], noise_std=0) - targets).mean()
    for _ in range(400):
        idx = rng.integers(0, m_rows, size=(3, 64))
        out = m.update({k: v[idx] for k, v in rows.items()})
    assert out["critic_grad_norm"].shape == (3,) and out["td_abs"].shape == (3, 64)
    d1 = np.abs(m.act(obs[:200], noise_std=0) - targets).mean()
    assert d1 < 0.5 * d0, (d0, d1)
    twin = MADDPG(3, 4, 2, networks="shared", seed=5)
    twin.load_state_dict(m.state_dict())
    np.testing.assert_array_equal(twin.act(obs[:10], noise_std=0), m.act(obs[:10], noise_std=0))

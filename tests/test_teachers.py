"""K-fold teachers (ALGORITHM.md §3.2, §7 properties 11-14)."""

import io

import numpy as np
import pytest
import torch

from cmcl.learners.maddpg import MADDPG
from cmcl.learners.nets import joint_input
from cmcl.learners.network_steps import teacher_fit_batch
from cmcl.replay.buffer_steps import fold_draw_indices
from cmcl.scorers.difficulty import cross_validated_difficulty
from cmcl.scorers.teachers import TeacherEnsemble

torch.set_num_threads(1)

N, OD, AD, K = 3, 5, 2, 4
IN = N * (OD + AD)


def buffer(m=400, seed=0):
    """Joint rows plus a fold per row assigned by 'episode' (10-step episodes, episode mod K)."""
    rng = np.random.default_rng(seed)
    return {
        "obs": rng.normal(size=(m, N, OD)).astype(np.float32),
        "act": rng.uniform(-1, 1, size=(m, N, AD)).astype(np.float32),
        "rew": rng.normal(size=(m, N)).astype(np.float32),
        "next_obs": rng.normal(size=(m, N, OD)).astype(np.float32),
        "done": np.zeros(m, np.float32),
    }, (np.arange(m) // 10) % K


def fold_batch_indices(fold, k, s, rng, num_agents=1):
    """int64[B, K, S] row indices, each [b, i] drawn from fold i only."""
    return fold_draw_indices(fold, range(k), s, rng, draws=num_agents)[0]


def make_fit_batch(idx, data, agents, m):
    """One fit step's (x [A, K, S, in], y [A, K, S]) for index sets idx [B, K, S] into the rows `data`."""
    x, y = teacher_fit_batch({k: v[idx][None] for k, v in data.items()}, np.asarray(agents), m)
    return x[:, 0], y[:, 0]


def difficulty(ens, x, y, fold):
    """c [A, M] of eq. (11) from every teacher's errors on rows x (all K teachers have scored)."""
    c, ok = cross_validated_difficulty(ens.errors(x, y).transpose(1, 0, 2), fold)
    assert ok.all()
    return c.T


def test_property_11_fold_batches_only_from_own_fold():
    _, fold = buffer()
    idx = fold_batch_indices(fold, K, 64, np.random.default_rng(0), num_agents=2)
    assert idx.shape == (2, K, 64) and idx.dtype == np.int64
    for i in range(K):
        assert (fold[idx[:, i]] == i).all()
    # draws cover the fold (uniform within it) and differ between agents
    assert len(np.unique(idx[0, 1])) > 40 and not np.array_equal(idx[0], idx[1])
    with pytest.raises(ValueError):
        fold_batch_indices(np.zeros(10, np.int64), K, 4, np.random.default_rng(0))


def test_make_fit_batch_uses_learner_td_targets():
    data, fold = buffer()
    m = MADDPG(N, OD, AD, seed=0)
    agents = [0, 2]
    idx = fold_batch_indices(fold, K, 16, np.random.default_rng(1), num_agents=2)
    x, y = make_fit_batch(idx, data, agents, m)
    assert x.shape == (2, K, 16, IN) and y.shape == (2, K, 16)
    y_all = m.td_targets(data["rew"], data["next_obs"], data["done"], agents=agents)  # [2, M]
    x_all = joint_input(torch.as_tensor(data["obs"]), torch.as_tensor(data["act"]))
    for a in range(2):
        np.testing.assert_allclose(y[a].numpy(), y_all[a][idx[a]], rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(x[a], x_all[idx[a]])


def _make_identical(ens):
    """Copy member 0's weights into every member so all teachers compute the same function."""
    with torch.no_grad():
        for p in ens.net.parameters():
            p.copy_(p[0:1].expand_as(p))


@pytest.mark.parametrize("bad_fold", range(K))
def test_property_12_own_fold_teacher_never_scores_its_samples(bad_fold):
    data, fold = buffer()
    ens = TeacherEnsemble(2, in_dim=IN, num_folds=K, seed=0)
    _make_identical(ens)
    x = joint_input(torch.as_tensor(data["obs"]), torch.as_tensor(data["act"]))
    y = ens.predict(x)[:, :, 0]  # [A, M]: every teacher matches y exactly
    last = ens.net.layers[-1]
    with torch.no_grad():
        for a in range(2):
            last.bias[a * K + bad_fold] += 1e9
    c = difficulty(ens, x, y, fold)
    own = fold == bad_fold
    assert c.shape == (2, len(fold))
    assert np.abs(c[:, own]).max() <= 1e-6
    assert (c[:, ~own] > 1e17).all()  # the other folds' samples do see the huge teacher
    other = (bad_fold + 1) % K
    with torch.no_grad():
        last.bias[other] += 0.5  # perturb teacher i != f(j) of agent 0
    c2 = difficulty(ens, x, y, fold)
    np.testing.assert_allclose(c2[0, own], 0.25, rtol=1e-3)
    assert np.abs(c2[1, own]).max() <= 1e-6


def test_property_13_sum_over_blind_teachers_and_its_partial_form():
    rng = np.random.default_rng(0)
    e = rng.exponential(size=(300, 2, K)).astype(np.float32)  # [M, A, K]
    fold = rng.integers(0, K, size=300)
    c, ok = cross_validated_difficulty(e, fold)
    mask = fold[:, None] != np.arange(K)[None]
    assert ok.all()
    np.testing.assert_allclose(c, (e * mask[:, None, :]).sum(-1), rtol=1e-6)  # eq. (11): the sum over i != f(j)
    # only some blind teachers have scored (the service): (K-1)·mean over those, and nothing without any
    scored = rng.random((300, K)) < 0.5
    part, ok = cross_validated_difficulty(e, fold, scored)
    blind = mask & scored
    want = (e * blind[:, None, :]).sum(-1) * ((K - 1) / np.maximum(blind.sum(1), 1))[:, None]
    np.testing.assert_allclose(part, want, rtol=1e-6)
    np.testing.assert_array_equal(ok, blind.any(1))
    assert (part[~ok] == 0).all()


def test_property_14_difficulty_ignores_online_critic_until_teachers_update():
    data, fold = buffer()
    m = MADDPG(N, OD, AD, seed=0)
    ens = TeacherEnsemble(N, in_dim=IN, num_folds=K, seed=1)
    agents = np.arange(N)
    x = joint_input(torch.as_tensor(data["obs"]), torch.as_tensor(data["act"]))

    def score():
        y = m.td_targets(data["rew"], data["next_obs"], data["done"], agents=agents)
        return difficulty(ens, x, y, fold)

    c0 = score()
    with torch.no_grad():
        for p in [*m.critic.parameters(), *m.actor.parameters()]:
            p.mul_(1.5).add_(0.1)
    np.testing.assert_array_equal(score(), c0)
    idx = fold_batch_indices(fold, K, 32, np.random.default_rng(0), num_agents=N)
    ens.fit_step(*make_fit_batch(idx, data, agents, m))
    assert not np.allclose(score(), c0)


def test_fit_step_lowers_loss_on_fixed_fold_batch_and_members_independent():
    data, fold = buffer()
    m = MADDPG(N, OD, AD, seed=0)
    ens = TeacherEnsemble(2, in_dim=IN, num_folds=K, seed=0)
    idx = fold_batch_indices(fold, K, 64, np.random.default_rng(0), num_agents=2)
    x, y = make_fit_batch(idx, data, [0, 1], m)
    first = ens.fit_step(x, y)
    assert first.shape == (2, K)
    for _ in range(30):
        last = ens.fit_step(x, y)
    assert (last < first).all()
    # a member's step depends only on its own batch: corrupt (1, 3)'s targets, others' trajectory is unchanged
    ens_a = TeacherEnsemble(2, in_dim=IN, num_folds=K, seed=5)
    ens_b = TeacherEnsemble(2, in_dim=IN, num_folds=K, seed=5)
    y_bad = y.clone()
    y_bad[1, 3] += 100.0
    for _ in range(3):
        la, lb = ens_a.fit_step(x, y), ens_b.fit_step(x, y_bad)
    np.testing.assert_allclose(la.ravel()[:-1], lb.ravel()[:-1], rtol=1e-6)
    assert la[1, 3] != lb[1, 3]


def test_errors_shape_chunking_and_abs():
    ens = TeacherEnsemble(2, in_dim=IN, num_folds=K, chunk_size=37, seed=0)
    x = torch.randn(100, IN)
    y = torch.randn(2, 100)
    e = ens.errors(x, y)
    assert e.shape == (2, 100, K) and e.dtype == np.float32 and (e >= 0).all()
    pred = torch.stack([torch.stack([ens.net.member_module(a * K + i)(x).squeeze(-1) for i in range(K)], -1)
                        for a in range(2)]).detach().numpy()
    np.testing.assert_allclose(e, (y.numpy()[..., None] - pred) ** 2, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(ens.errors(x, y, squared=False) ** 2, e, rtol=1e-4, atol=1e-5)


def test_state_dict_round_trip():
    data, fold = buffer()
    m = MADDPG(N, OD, AD, seed=0)
    ens = TeacherEnsemble(2, in_dim=IN, num_folds=K, seed=0)
    idx = fold_batch_indices(fold, K, 16, np.random.default_rng(0), num_agents=2)
    batch = make_fit_batch(idx, data, [0, 1], m)
    ens.fit_step(*batch)
    buf = io.BytesIO()
    torch.save(ens.state_dict(), buf)
    buf.seek(0)
    ens2 = TeacherEnsemble(2, in_dim=IN, num_folds=K, seed=99)
    ens2.load_state_dict(torch.load(buf, weights_only=True))
    np.testing.assert_array_equal(ens2.fit_step(*batch), ens.fit_step(*batch))
    x = torch.randn(10, IN)
    np.testing.assert_array_equal(ens2.predict(x), ens.predict(x))


def test_make_fit_batch_shared_fold_batches():
    data, fold = buffer()
    m = MADDPG(N, OD, AD, seed=0)
    idx = fold_batch_indices(fold, K, 16, np.random.default_rng(1), num_agents=1)
    x, y = make_fit_batch(idx, data, [1, 2], m)
    assert x.shape == (2, K, 16, IN) and y.shape == (2, K, 16)
    torch.testing.assert_close(x[0], x[1])
    y_all = m.td_targets(data["rew"], data["next_obs"], data["done"], agents=[1, 2])
    np.testing.assert_allclose(y.numpy(), y_all[:, idx[0]], rtol=1e-5, atol=1e-5)
    with pytest.raises(ValueError):
        make_fit_batch(np.zeros((3, K, 4), np.int64), data, [1, 2], m)


def test_shared_teachers_are_one_network_per_fold_and_folds_stay_independent():
    """networks = "shared": parameters ~A times fewer; a corrupt target in fold 3 moves only fold 3's teachers
    (of every agent, since they share fold 3's network), never another fold's (eq. 11 needs that)."""
    data, fold = buffer()
    m = MADDPG(N, OD, AD, seed=0)
    own = TeacherEnsemble(N, in_dim=IN, num_folds=K, seed=5)
    shared = TeacherEnsemble(N, in_dim=IN, num_folds=K, seed=5, networks="shared")
    count = [sum(p.numel() for p in e.net.parameters()) for e in (own, shared)]
    assert count[1] < count[0] / (N - 1), count
    idx = fold_batch_indices(fold, K, 64, np.random.default_rng(0), num_agents=N)
    x, y = make_fit_batch(idx, data, list(range(N)), m)
    y_bad = y.clone()
    y_bad[1, 3] += 100.0
    first = shared.fit_step(x, y)
    for _ in range(30):
        last = shared.fit_step(x, y)
    assert (last < first).all()
    clean = TeacherEnsemble(N, in_dim=IN, num_folds=K, seed=5, networks="shared")
    corrupt = TeacherEnsemble(N, in_dim=IN, num_folds=K, seed=5, networks="shared")
    for _ in range(3):
        la, lb = clean.fit_step(x, y), corrupt.fit_step(x, y_bad)
    np.testing.assert_allclose(la[:, :3], lb[:, :3], rtol=1e-6)  # folds 0-2 never see fold 3's targets
    assert (la[:, 3] != lb[:, 3]).all()  # fold 3's network is shared: every agent's fold-3 teacher moved
    errors = corrupt.errors(x[0, 0], y[:, 0])  # [A, S, K]: still one prediction per (agent, fold)
    assert errors.shape == (N, x.shape[2], K)


def test_a_fold_batch_shared_by_the_agents_fits_shared_teachers_as_its_copies_do():
    """The fast path of shared teachers (first layer once per fold when x is one batch expanded over agents)
    takes the same Adam steps as the same rows copied to every agent."""
    data, fold = buffer()
    m = MADDPG(N, OD, AD, seed=0)
    idx = fold_batch_indices(fold, K, 32, np.random.default_rng(1), num_agents=1)
    x, y = make_fit_batch(idx, data, list(range(N)), m)
    x_shared = x[:1].expand(N, -1, -1, -1)
    fast, slow = (TeacherEnsemble(N, in_dim=IN, num_folds=K, seed=7, networks="shared") for _ in range(2))
    for _ in range(3):
        np.testing.assert_allclose(fast.fit_step(x_shared, y), slow.fit_step(x_shared.contiguous(), y), rtol=1e-5)
    for p, q in zip(fast.net.parameters(), slow.net.parameters(), strict=True):
        torch.testing.assert_close(p, q)

"""Entity teachers (teachers.networks = "entity"): one entity critic per fold for all agents, folds independent."""

import numpy as np
import pytest
import torch

from cmcl.envs.entities import spread_layout
from cmcl.learners.maddpg import MADDPG
from cmcl.learners.nets import joint_input
from cmcl.scorers.teachers import TeacherEnsemble
from tests.test_teachers import fold_batch_indices, make_fit_batch

torch.set_num_threads(1)

N, AD, K = 3, 2, 4
LAYOUT = spread_layout(N)
OD = LAYOUT.obs_dim
IN = N * (OD + AD)


def buffer(m=400, seed=0):
    rng = np.random.default_rng(seed)
    data = {"obs": rng.normal(size=(m, N, OD)).astype(np.float32),
            "act": rng.uniform(-1, 1, size=(m, N, AD)).astype(np.float32),
            "rew": rng.normal(size=(m, N)).astype(np.float32),
            "next_obs": rng.normal(size=(m, N, OD)).astype(np.float32), "done": np.zeros(m, np.float32)}
    return data, (np.arange(m) // 10) % K


def teachers(agents=(0, 1, 2), seed=5, layout=LAYOUT, n=N):
    return TeacherEnsemble(len(agents), in_dim=n * (layout.obs_dim + AD), num_folds=K, hidden=32, seed=seed,
                           networks="entity", agents=list(agents), entity_layout=layout, act_dim=AD)


def test_entity_teachers_fit_and_a_corrupt_fold_moves_only_its_own_network():
    data, fold = buffer()
    m = MADDPG(N, OD, AD, seed=0)
    idx = fold_batch_indices(fold, K, 64, np.random.default_rng(0), num_agents=N)
    x, y = make_fit_batch(idx, data, list(range(N)), m)
    ens = teachers()
    first = ens.fit_step(x, y)
    for _ in range(30):
        last = ens.fit_step(x, y)
    assert first.shape == (N, K) and last.mean() < first.mean()
    y_bad = y.clone()
    y_bad[1, 3] += 100.0
    clean, corrupt = teachers(), teachers()
    for _ in range(3):
        la, lb = clean.fit_step(x, y), corrupt.fit_step(x, y_bad)
    np.testing.assert_allclose(la[:, :3], lb[:, :3], rtol=1e-6)  # folds 0-2 never see fold 3's targets
    assert (la[:, 3] != lb[:, 3]).all()  # fold 3's one network serves every agent's fold-3 teacher
    for k, (pa, pb) in enumerate(zip(clean.net.parameters(), corrupt.net.parameters(), strict=True)):
        assert torch.equal(pa[:3], pb[:3]), k  # group axis = fold: folds 0-2 bit for bit the same


def test_predictions_follow_the_teachers_agents_and_match_the_fit_path():
    data, _ = buffer(m=50)
    x = joint_input(torch.as_tensor(data["obs"]), torch.as_tensor(data["act"]))  # [M, in]
    every, only_two = teachers((0, 1, 2)), teachers((2,))
    p_every, p_two = every.predict(x), only_two.predict(x)  # [A, M, K]
    assert p_every.shape == (N, 50, K) and p_two.shape == (1, 50, K)
    np.testing.assert_allclose(p_two[0], p_every[2], atol=1e-6)  # the same fold networks, agent 2's Q
    assert not np.allclose(p_every[0], p_every[2], atol=1e-4)
    # the fit path scores the same rows the same: loss of fit_step on y = 0 is the mean square prediction
    xs = x[:16].unsqueeze(0).unsqueeze(0).expand(N, K, -1, -1)
    loss = every.fit_step(xs, torch.zeros(N, K, 16))
    np.testing.assert_allclose(loss, (p_every[:, :16] ** 2).mean(1), rtol=1e-5)


def test_entity_teacher_size_does_not_depend_on_n_and_checkpoints_name_the_setting():
    sizes = []
    for n in (4, 8):
        layout = spread_layout(n)
        sizes.append(sum(p.numel() for p in teachers(tuple(range(n)), layout=layout, n=n).net.parameters()))
    assert sizes[0] == sizes[1]
    ens = teachers()
    again = teachers(seed=9)
    again.load_state_dict(ens.state_dict())
    data, _ = buffer(m=20)
    x = joint_input(torch.as_tensor(data["obs"]), torch.as_tensor(data["act"]))
    np.testing.assert_array_equal(again.predict(x), ens.predict(x))
    with pytest.raises(ValueError, match="teachers.networks"):
        TeacherEnsemble(N, in_dim=IN, num_folds=K, hidden=32).load_state_dict(ens.state_dict())
    with pytest.raises(ValueError, match="entity layout"):
        TeacherEnsemble(N, in_dim=IN, num_folds=K, networks="entity")

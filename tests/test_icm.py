"""ICM (ALGORITHM.md §3.4, §7 properties 23-25; 26 is in test_maddpg.py)."""

import io

import numpy as np
import torch

from cmcl.scorers.icm import ICM

torch.set_num_threads(1)

A, OD, AD = 2, 6, 2


def rand_batch(m=50, seed=0, od=OD, ad=AD):
    g = torch.Generator().manual_seed(seed)
    o, a = torch.randn(A, m, od, generator=g), torch.rand(A, m, ad, generator=g) * 2 - 1
    return o, a, torch.randn(A, m, od, generator=g)


def test_property_23_shapes():
    icm = ICM(A, OD, AD, seed=0)
    o, a, o2 = rand_batch()
    f = icm.phi(o)
    assert f.shape == (A, 50, 32)
    assert icm.inverse(torch.cat([f, icm.phi(o2)], -1)).shape == (A, 50, AD)
    assert icm.forward_model(torch.cat([f, a], -1)).shape == (A, 50, 32)
    out = icm.train_step(o, a, o2)
    assert out["inverse_loss"].shape == (A,) and out["forward_loss"].shape == (A,)
    assert isinstance(out["total"], float)
    rho = icm.curiosity(o.numpy(), a.numpy(), o2.numpy())
    assert rho.shape == (A, 50) and rho.dtype == np.float32


def test_property_24_rho_nonnegative_formula_and_zero_when_prediction_exact():
    icm = ICM(A, OD, AD, chunk_size=7, seed=0)
    o, a, o2 = rand_batch(m=40)
    rho = icm.curiosity(o, a, o2)
    assert (rho >= 0).all() and (rho > 0).any()
    with torch.no_grad():
        ref = 0.5 * (icm.forward_model(torch.cat([icm.phi(o), a], -1)) - icm.phi(o2)).pow(2).sum(-1)
    np.testing.assert_allclose(rho, ref.numpy(), rtol=1e-5, atol=1e-6)
    # constant encoder b and a forward model that outputs b: prediction == phi(o') exactly -> rho == 0
    with torch.no_grad():
        icm.phi.layers[-1].weight.zero_()
        icm.forward_model.layers[-1].weight.zero_()
        icm.forward_model.layers[-1].bias.copy_(icm.phi.layers[-1].bias)
    assert np.array_equal(icm.curiosity(o, a, o2), np.zeros((A, 40), np.float32))


def test_property_25_toy_dynamics_learned_and_novel_states_more_curious():
    """o' = o + a (obs_dim = act_dim = 2): L_I and L_F fall; seen transitions end less curious than novel ones."""
    g = torch.Generator().manual_seed(0)
    o = torch.randn(A, 256, 2, generator=g)
    a = torch.rand(A, 256, 2, generator=g) * 2 - 1
    o_new = torch.randn(A, 256, 2, generator=g) * 0.5 + 4.0  # held-out: a region never seen
    a_new = torch.rand(A, 256, 2, generator=g) * 2 - 1
    o_same = torch.randn(A, 256, 2, generator=g)  # held-out from the training distribution
    a_same = torch.rand(A, 256, 2, generator=g) * 2 - 1
    icm = ICM(A, 2, 2, seed=0)
    first = icm.losses(o, a, o + a)
    for step in range(400):
        sl = slice((step * 64) % 256, (step * 64) % 256 + 64)
        icm.train_step(o[:, sl], a[:, sl], o[:, sl] + a[:, sl])
    last = icm.losses(o, a, o + a)
    assert (last["inverse_loss"] < 0.5 * first["inverse_loss"]).all(), (first, last)
    assert (last["forward_loss"] < first["forward_loss"]).all(), (first, last)
    seen = icm.curiosity(o, a, o + a).mean(1)
    held_same = icm.curiosity(o_same, a_same, o_same + a_same).mean(1)
    held_novel = icm.curiosity(o_new, a_new, o_new + a_new).mean(1)
    assert (seen < held_same).all() and (held_same < held_novel).all(), (seen, held_same, held_novel)


def test_members_train_independently():
    o, a, o2 = rand_batch(m=32)
    i1, i2 = ICM(A, OD, AD, seed=3), ICM(A, OD, AD, seed=3)
    a_bad = a.clone()
    a_bad[1] = -a_bad[1]
    for _ in range(3):
        r1, r2 = i1.train_step(o, a, o2), i2.train_step(o, a_bad, o2)
    np.testing.assert_allclose(r1["inverse_loss"][0], r2["inverse_loss"][0], rtol=1e-6)
    np.testing.assert_allclose(r1["forward_loss"][0], r2["forward_loss"][0], rtol=1e-6)
    assert r1["inverse_loss"][1] != r2["inverse_loss"][1]


def test_discrete_inverse_loss_is_cross_entropy():
    icm = ICM(A, OD, 5, discrete=True, seed=0)
    g = torch.Generator().manual_seed(1)
    o, o2 = torch.randn(A, 20, OD, generator=g), torch.randn(A, 20, OD, generator=g)
    labels = torch.randint(0, 5, (A, 20), generator=g)
    act = torch.nn.functional.one_hot(labels, 5).float()
    inv = icm.losses(o, act, o2)["inverse_loss"]
    with torch.no_grad():
        logits = icm.inverse(torch.cat([icm.phi(o), icm.phi(o2)], -1))
    ref = [torch.nn.functional.cross_entropy(logits[k], labels[k]).item() for k in range(A)]
    np.testing.assert_allclose(inv, ref, rtol=1e-5)
    assert np.isfinite(icm.train_step(o, act, o2)["total"])


def test_state_dict_round_trip():
    o, a, o2 = rand_batch()
    icm = ICM(A, OD, AD, seed=0)
    icm.train_step(o, a, o2)
    buf = io.BytesIO()
    torch.save(icm.state_dict(), buf)
    buf.seek(0)
    icm2 = ICM(A, OD, AD, seed=7)
    icm2.load_state_dict(torch.load(buf, weights_only=True))
    np.testing.assert_array_equal(icm2.curiosity(o, a, o2), icm.curiosity(o, a, o2))
    r1, r2 = icm.train_step(o, a, o2), icm2.train_step(o, a, o2)
    np.testing.assert_array_equal(r1["forward_loss"], r2["forward_loss"])

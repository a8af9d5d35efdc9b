"""StackedMLP equals per-member nn.Linear stacks; per-member helpers equal their per-module torch counterparts."""

import copy

import pytest
import torch
from torch import nn

from cmcl.learners.nets import StackedMLP, clip_grad_norm_per_member_, hard_update_, joint_input, soft_update_

torch.set_num_threads(1)


def test_stacked_mlp_matches_loop_of_linear_layers():
    net = StackedMLP(5, 7, (16, 12), 3, out_act=nn.Tanh, seed=1)
    x = torch.randn(5, 9, 7, generator=torch.Generator().manual_seed(2))
    out = net(x)
    assert out.shape == (5, 9, 3)
    for m in range(5):
        seq = net.member_module(m)
        assert isinstance(seq[0], nn.Linear) and isinstance(seq[-1], nn.Tanh)
        torch.testing.assert_close(out[m], seq(x[m]), rtol=1e-5, atol=1e-6)


def test_manual_linear_copy_and_shared_input_and_member_subset():
    net = StackedMLP(3, 4, (8,), 2, seed=3)
    lins = []
    for m in range(3):
        l1, l2 = nn.Linear(4, 8), nn.Linear(8, 2)
        with torch.no_grad():
            l1.weight.copy_(net.layers[0].weight[m].T)
            l1.bias.copy_(net.layers[0].bias[m])
            l2.weight.copy_(net.layers[1].weight[m].T)
            l2.bias.copy_(net.layers[1].bias[m])
        lins.append(nn.Sequential(l1, nn.ReLU(), l2))
    x = torch.randn(6, 4)
    shared = net(x)  # [3, 6, 2]
    for m in range(3):
        torch.testing.assert_close(shared[m], lins[m](x), rtol=1e-5, atol=1e-6)
    sub = net(x, torch.tensor([2, 0]))
    torch.testing.assert_close(sub, shared[[2, 0]])


def test_init_matches_nn_linear_bounds_and_members_differ():
    net = StackedMLP(4, 50, (64,), 1, seed=0)
    w = net.layers[0].weight
    assert w.abs().max() <= 1 / 50**0.5 and w.abs().max() > 0.9 / 50**0.5
    assert not torch.equal(w[0], w[1])
    # uniform on [-b, b] has std b / sqrt(3); pooled over all members
    assert abs(w.std().item() - (1 / 50**0.5) / 3**0.5) < 0.01
    same = StackedMLP(4, 50, (64,), 1, seed=0)
    assert torch.equal(same.layers[0].weight, w)


def test_per_member_grad_clip_equals_clip_grad_norm():
    net = StackedMLP(4, 6, (10, 10), 2, seed=5)
    x = torch.randn(4, 32, 6)
    scale = torch.tensor([0.01, 1.0, 10.0, 100.0]).view(4, 1, 1)  # some members below, some above the limit
    (net(x) * scale).pow(2).sum().backward()
    seqs = [net.member_module(m) for m in range(4)]
    for m, seq in enumerate(seqs):
        (seq(x[m]) * scale[m]).pow(2).sum().backward()
    norms = clip_grad_norm_per_member_(net.parameters(), 0.5)
    for m, seq in enumerate(seqs):
        ref_norm = torch.nn.utils.clip_grad_norm_(seq.parameters(), 0.5)
        torch.testing.assert_close(norms[m], ref_norm, rtol=1e-5, atol=1e-7)
        lin0, lin1, lin2 = seq[0], seq[2], seq[4]
        for k, lin in enumerate((lin0, lin1, lin2)):
            torch.testing.assert_close(net.layers[k].weight.grad[m], lin.weight.grad.T, rtol=1e-4, atol=1e-7)
            torch.testing.assert_close(net.layers[k].bias.grad[m], lin.bias.grad, rtol=1e-4, atol=1e-7)
    assert norms[0] < 0.5 and norms[3] > 0.5


def test_soft_and_hard_update():
    src = StackedMLP(2, 3, (4,), 1, seed=0)
    tgt = StackedMLP(2, 3, (4,), 1, seed=1)
    before = copy.deepcopy(tgt)
    soft_update_(tgt, src, 0.01)
    for t, b, s in zip(tgt.parameters(), before.parameters(), src.parameters(), strict=True):
        torch.testing.assert_close(t, 0.01 * s + 0.99 * b, rtol=0, atol=1e-7)
    hard_update_(tgt, src)
    for t, s in zip(tgt.parameters(), src.parameters(), strict=True):
        assert torch.equal(t, s)


def test_joint_input_layout():
    obs = torch.arange(2 * 3 * 2, dtype=torch.float32).view(2, 3, 2)
    act = -torch.arange(2 * 3 * 1, dtype=torch.float32).view(2, 3, 1)
    x = joint_input(obs, act)
    assert x.shape == (2, 9)
    torch.testing.assert_close(x[1], torch.cat([obs[1].flatten(), act[1].flatten()]))


def assert_each_member_is_its_own_module(net: StackedMLP, x: torch.Tensor, subset: list[int]) -> torch.Tensor:
    """net(x) equals member_module(m)(x[m]) for every member, and a member subset equals those rows; -> net(x)."""
    out = net(x)
    for m in range(net.members):
        torch.testing.assert_close(out[m], net.member_module(m)(x[m]))
    torch.testing.assert_close(net(x[subset], torch.tensor(subset)), out[subset])
    return out


def test_a_shared_mlp_is_one_network_with_a_per_member_first_layer_bias():
    shared, own = StackedMLP(5, 7, (16, 16), 3, seed=0, share=True), StackedMLP(5, 7, (16, 16), 3, seed=0)
    shapes = [tuple(p.shape) for p in shared.parameters()]
    assert shapes == [(1, 7, 16), (5, 16), (1, 16, 16), (1, 16), (1, 16, 3), (1, 3)], shapes
    assert sum(p.numel() for p in shared.parameters()) < sum(p.numel() for p in own.parameters()) / 4
    x = torch.randn(5, 11, 7)
    assert_each_member_is_its_own_module(shared, x, [3, 1])
    torch.testing.assert_close(shared(x[0])[2], shared.member_module(2)(x[0]))  # one input shared by all members
    with torch.no_grad():
        shared.layers[0].bias[4].copy_(shared.layers[0].bias[0])
    same = shared(x[0].expand(5, 11, 7))
    torch.testing.assert_close(same[4], same[0])  # only the first-layer bias tells members apart
    assert not torch.allclose(same[1], same[0])


def test_the_grad_clip_of_a_shared_network_is_one_global_norm():
    net = StackedMLP(4, 6, (8,), 2, seed=1, share=True)
    twin = copy.deepcopy(net)
    for model in (net, twin):
        (model(torch.randn(4, 9, 6, generator=torch.Generator().manual_seed(2))) * 50).sum().backward()
    norms = clip_grad_norm_per_member_(net.parameters(), 0.5)
    expected = torch.nn.utils.clip_grad_norm_(list(twin.parameters()), 0.5)
    torch.testing.assert_close(norms, expected.expand(4))
    for p, q in zip(net.parameters(), twin.parameters(), strict=True):
        torch.testing.assert_close(p.grad, q.grad)


def test_grouped_sharing_gives_member_m_the_network_of_group_m_mod_g():
    net = StackedMLP(6, 5, (8,), 1, seed=3, share=True, share_groups=3)
    shapes = [tuple(p.shape) for p in net.parameters()]
    assert shapes == [(3, 5, 8), (6, 8), (3, 8, 1), (3, 1)], shapes
    x = torch.randn(6, 4, 5)
    assert_each_member_is_its_own_module(net, x, [5, 0])
    with torch.no_grad():  # members 1 and 4 share group 1: equal first-layer biases make them one function
        net.layers[0].bias[4].copy_(net.layers[0].bias[1])
        net.layers[0].bias[3].copy_(net.layers[0].bias[1])
    same = net(x[0])
    torch.testing.assert_close(same[4], same[1])
    assert not torch.allclose(same[3], same[1])  # member 3 is in group 0: another network
    with pytest.raises(ValueError, match="groups must divide members=6, got 4"):
        StackedMLP(6, 5, (8,), 1, share=True, share_groups=4)


def test_a_group_never_gets_the_gradient_of_another_groups_members():
    net = StackedMLP(6, 5, (8,), 1, seed=3, share=True, share_groups=3)
    loss = net(torch.randn(6, 4, 5))[[0, 3]].sum()  # members 0 and 3: group 0 only
    loss.backward()
    for p in net.parameters():
        rows = p.grad.reshape(p.shape[0], -1).abs().sum(1)
        owners = torch.arange(p.shape[0]) % 3 if p.shape[0] == 6 else torch.arange(3)
        assert (rows[owners != 0] == 0).all() and (rows[owners == 0] > 0).any()


def test_the_grad_clip_of_grouped_networks_is_one_norm_per_group():
    net = StackedMLP(6, 5, (8,), 2, seed=4, share=True, share_groups=2)
    (net(torch.randn(6, 9, 5, generator=torch.Generator().manual_seed(5))) * 50).sum().backward()
    before = [p.grad.clone() for p in net.parameters()]
    norms = clip_grad_norm_per_member_(net.parameters(), 0.5)
    for group in range(2):  # the group's slices of every parameter, as one network
        slices = [g.reshape(g.shape[0] // 2, 2, -1)[:, group] for g in before]
        expected = torch.cat([s.flatten() for s in slices]).norm()
        torch.testing.assert_close(norms[group::2], expected.expand(3))
        clipped = [p.grad.reshape(p.shape[0] // 2, 2, -1)[:, group] for p in net.parameters()]
        torch.testing.assert_close(torch.cat([c.flatten() for c in clipped]).norm(), torch.tensor(0.5), rtol=1e-4,
                                   atol=0)


def test_one_input_per_group_equals_that_input_given_to_every_member_of_the_group():
    net = StackedMLP(6, 5, (8,), 2, seed=6, share=True, share_groups=3)
    per_group = torch.randn(3, 4, 5)
    per_member = per_group.repeat(2, 1, 1)  # member m reads per_group[m % 3]
    torch.testing.assert_close(net(per_group), net(per_member))
    shared = per_group[0]
    torch.testing.assert_close(net(shared), net(shared.expand(6, 4, 5)))

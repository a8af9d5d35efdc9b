"""The learner's lean paths are the previous arithmetic bit for bit: the optimiser step (cmcl.learners.nets.adam_step_,
drop_grads_) is torch.optim's with the same optimiser state (checkpoints load as before), the gradient clip is the
previous clip, and shared rows through per-member weights (one baddbmm on a view) give matmul's numbers."""

import copy

import torch

from cmcl.learners.nets import StackedMLP, adam_step_, clip_grad_norm_per_member_, drop_grads_, make_adam

torch.set_num_threads(1)


def _loss(net: StackedMLP, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    x, y = torch.randn(4, 32, 10, generator=g), torch.randn(4, 32, 1, generator=g)
    return (net(x) - y).pow(2).mean((1, 2)).sum()


def test_adam_step_equals_opt_step_bit_for_bit_with_the_same_state():
    ref = StackedMLP(4, 10, (16, 16), 1, seed=0)
    lean = copy.deepcopy(ref)
    ref_opt, lean_opt = make_adam(ref.parameters(), 1e-2), make_adam(lean.parameters(), 1e-2)
    for step in range(6):
        if step == 3:  # a checkpoint round trip replaces every state tensor: the lean step must follow
            lean_opt.load_state_dict(copy.deepcopy(lean_opt.state_dict()))
        ref_opt.zero_grad(set_to_none=True)
        _loss(ref, step).backward()
        ref_opt.step()
        drop_grads_(lean.parameters())
        _loss(lean, step).backward()
        adam_step_(lean_opt)
        for p, q in zip(ref.parameters(), lean.parameters(), strict=True):
            assert torch.equal(p, q)
    ref_state, lean_state = ref_opt.state_dict(), lean_opt.state_dict()
    assert ref_state["param_groups"] == lean_state["param_groups"]
    for k, st in ref_state["state"].items():
        assert st.keys() == lean_state["state"][k].keys()
        for name, value in st.items():
            assert torch.equal(value, lean_state["state"][k][name]), name


def test_adam_step_without_the_fused_kernel_is_opt_step():
    ref = StackedMLP(2, 10, (8,), 1, seed=1)
    lean = copy.deepcopy(ref)
    ref_opt = torch.optim.Adam(ref.parameters(), lr=1e-2, foreach=False)
    lean_opt = torch.optim.Adam(lean.parameters(), lr=1e-2, foreach=False)
    for step in range(3):
        for net, opt, stepper in ((ref, ref_opt, ref_opt.step), (lean, lean_opt, lambda o=lean_opt: adam_step_(o))):
            opt.zero_grad(set_to_none=True)
            (net(torch.ones(2, 3, 10) * step) - 1).pow(2).sum().backward()
            stepper()
    for p, q in zip(ref.parameters(), lean.parameters(), strict=True):
        assert torch.equal(p, q)


def test_drop_grads_leaves_no_gradient():
    net = StackedMLP(2, 3, (4,), 1, seed=2)
    net(torch.randn(2, 5, 3)).sum().backward()
    assert all(p.grad is not None for p in net.parameters())
    drop_grads_(net.parameters())
    assert all(p.grad is None for p in net.parameters())


def _previous_clip(grads: list[torch.Tensor], max_norm: float, eps: float = 1e-6) -> torch.Tensor:
    """The clip as it was written before the foreach version (pow, per-tensor sums, one mul_ each)."""
    groups = min(g.shape[0] for g in grads)
    sq = torch.stack([g.reshape(g.shape[0] // groups, groups, -1).pow(2).sum((0, 2)) for g in grads]).sum(0)
    norms = sq.sqrt()
    coef = (max_norm / (norms + eps)).clamp(max=1.0)
    for g in grads:
        g.view(g.shape[0] // groups, groups, -1).mul_(coef.view(1, groups, 1))
    return norms


def test_the_clip_is_the_previous_clip_bit_for_bit():
    for share in (False, True):
        net = StackedMLP(4, 10, (16, 16), 1, seed=3, share=share)
        _loss(net, 7).backward()
        grads = [p.grad.clone() for p in net.parameters()]
        norms = clip_grad_norm_per_member_(net.parameters(), 0.05)
        old = _previous_clip(grads, 0.05)
        assert torch.equal(norms, old.repeat(4 // old.shape[0]))
        for p, g in zip(net.parameters(), grads, strict=True):
            assert torch.equal(p.grad, g)


def test_shared_rows_through_per_member_weights_give_matmuls_numbers():
    for members, rows in ((4, 1024), (20, 300), (1, 77)):
        net = StackedMLP(members, 80, (64, 64), 1, seed=members)
        x = torch.randn(rows, 80, generator=torch.Generator().manual_seed(rows))
        with torch.no_grad():
            h = x
            for k, layer in enumerate(net.layers):  # the previous path: matmul broadcast, then the bias
                h = torch.matmul(h, layer.weight) + layer.bias.unsqueeze(1)
                h = h.relu() if k < len(net.layers) - 1 else h
            # the same numbers up to the kernels' summation order: bit-identical on some CPUs' BLAS, not on all
            torch.testing.assert_close(net(x), h, rtol=1e-6, atol=1e-6)


def _random_batch(rng, n: int = 3, s: int = 16, od: int = 6, ad: int = 2) -> dict:
    return {"obs": rng.normal(size=(n, s, n, od)).astype("float32"),
            "act": rng.uniform(-1, 1, size=(n, s, n, ad)).astype("float32"),
            "rew": rng.normal(size=(n, s, n)).astype("float32"),
            "next_obs": rng.normal(size=(n, s, n, od)).astype("float32"),
            "is_weights": rng.uniform(0.5, 1.0, size=(n, s)).astype("float32")}


def test_the_actor_step_by_hand_is_autograds_step_bit_for_bit(monkeypatch):
    import numpy as np

    from cmcl.learners import actor_grad
    from cmcl.learners.maddpg import MADDPG

    by_hand, by_autograd = MADDPG(3, 6, 2, hidden=16, seed=4), MADDPG(3, 6, 2, hidden=16, seed=4)
    assert actor_grad.supports(by_hand.actor, by_hand.critic)
    supports = actor_grad.supports
    for step in range(6):
        batch = _random_batch(np.random.default_rng(step))
        if step % 2:  # the actors' own rows (actor_batch = "uniform")
            extra = _random_batch(np.random.default_rng(100 + step), s=8)
            batch |= {"actor_obs": extra["obs"], "actor_act": extra["act"]}
        out = by_hand.update(batch)
        monkeypatch.setattr(actor_grad, "supports", lambda actor, critic: False)
        ref = by_autograd.update(batch)
        monkeypatch.setattr(actor_grad, "supports", supports)
        for key in ref:
            assert np.array_equal(out[key], ref[key], equal_nan=True), key
    for part in ("actor", "critic", "target_actor", "target_critic"):
        a, b = getattr(by_hand, part).state_dict(), getattr(by_autograd, part).state_dict()
        assert all(torch.equal(a[k], b[k]) for k in a), part
    a, b = by_hand.actor_opt.state_dict()["state"], by_autograd.actor_opt.state_dict()["state"]
    assert all(torch.equal(a[i]["exp_avg_sq"], b[i]["exp_avg_sq"]) for i in a)


def test_the_actor_step_by_hand_takes_only_plain_per_agent_networks():
    from cmcl.learners import actor_grad
    from cmcl.learners.maddpg import MADDPG

    assert not actor_grad.supports(*(lambda m: (m.actor, m.critic))(MADDPG(3, 6, 2, networks="shared")))
    assert not actor_grad.supports(*(lambda m: (m.actor, m.critic))(MADDPG(3, 6, 5, discrete=True)))

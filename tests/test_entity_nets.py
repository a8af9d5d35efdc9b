"""Entity actor and PIC-style critic (cmcl.learners.entity.nets): invariances, parameter counts, gradients."""

import copy

import numpy as np
import pytest
import torch

from cmcl.envs.entities import spread_layout, tag_layout
from cmcl.envs.params import TagParams
from cmcl.learners.entity import ops as entity_ops
from cmcl.learners.entity.nets import POOLS, EntityActor, EntityCritic, EntityEncoder
from cmcl.learners.nets import StackedLinear, joint_input


def spread_obs(pos, vel, lm):
    """Navigation's flat obs from the world state (as BatchedSparseSpread): pos, vel [M, N, 2], lm [M, L, 2]."""
    n = pos.shape[1]
    rows = []
    for i in range(n):
        others = [j for j in range(n) if j != i]
        rows.append(np.concatenate([vel[:, i], pos[:, i], (lm - pos[:, i : i + 1]).reshape(len(pos), -1),
                                    (pos[:, others] - pos[:, i : i + 1]).reshape(len(pos), -1)], -1))
    return torch.as_tensor(np.stack(rows, 1), dtype=torch.float32)  # [M, N, obs_dim]


def world(n, m=6, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(-0.5, 0.5, (m, n, 2)), rng.normal(0, 0.3, (m, n, 2)), rng.uniform(-0.4, 0.4, (m, n, 2))


def nets(n, hidden=32, seed=0, pool="attention"):
    gen = torch.Generator().manual_seed(seed)
    layout = spread_layout(n)
    return (EntityActor(layout, 2, hidden, gen, out_act=torch.nn.Tanh, pool=pool),
            EntityCritic(layout, 2, hidden, gen, pool=pool))


def count(module):
    return sum(p.numel() for p in module.parameters())


@pytest.mark.parametrize("pool", POOLS)
def test_actor_ignores_the_order_of_landmarks_and_other_agents(pool):
    n = 5
    actor, _ = nets(n, pool=pool)
    pos, vel, lm = world(n)
    obs = spread_obs(pos, vel, lm)
    out = actor(obs.transpose(0, 1))  # [N, M, 2]
    shuffled = spread_obs(pos, vel, lm[:, [3, 0, 4, 2, 1]])  # the landmarks listed in another order
    torch.testing.assert_close(actor(shuffled.transpose(0, 1)), out, atol=1e-5, rtol=1e-5)
    swapped = obs.clone()  # agent 0's view: the first two other agents' blocks exchanged
    base = 4 + 2 * n
    swapped[:, 0, base : base + 2], swapped[:, 0, base + 2 : base + 4] = obs[:, 0, base + 2 : base + 4], \
        obs[:, 0, base : base + 2]
    torch.testing.assert_close(actor(swapped.transpose(0, 1)), out, atol=1e-5, rtol=1e-5)
    moved = obs.clone()  # but moving a landmark changes the action
    moved[:, 0, 4:6] += 0.3
    assert not torch.allclose(actor(moved.transpose(0, 1))[0], out[0], atol=1e-4)


@pytest.mark.parametrize("pool", POOLS)
def test_critic_outputs_follow_a_permutation_of_the_agents_and_ignore_the_landmark_order(pool):
    n = 4
    _, critic = nets(n, pool=pool)
    pos, vel, lm = world(n, seed=1)
    act = torch.rand(6, n, 2) * 2 - 1
    q = critic(joint_input(spread_obs(pos, vel, lm), act))[..., 0]  # [N, M]
    perm = [2, 0, 3, 1]
    q_perm = critic(joint_input(spread_obs(pos[:, perm], vel[:, perm], lm), act[:, perm]))[..., 0]
    torch.testing.assert_close(q_perm, q[perm], atol=1e-5, rtol=1e-5)
    q_lm = critic(joint_input(spread_obs(pos, vel, lm[:, [1, 3, 0, 2]]), act))[..., 0]
    torch.testing.assert_close(q_lm, q, atol=1e-5, rtol=1e-5)
    assert not torch.allclose(q[0], q[1], atol=1e-4)  # the agents are told apart by what they see


def test_critic_is_centralised_it_reads_the_other_agents_actions_and_velocities():
    n = 3
    _, critic = nets(n)
    pos, vel, lm = world(n, seed=5)
    act = torch.rand(6, n, 2) * 2 - 1
    q = critic(joint_input(spread_obs(pos, vel, lm), act))[..., 0]
    other_act = act.clone()
    other_act[:, 2] = -other_act[:, 2]
    q_act = critic(joint_input(spread_obs(pos, vel, lm), other_act))[..., 0]
    assert not torch.allclose(q_act[0], q[0], atol=1e-5)  # agent 0's Q moves with agent 2's action
    other_vel = vel.copy()
    other_vel[:, 1] += 0.5
    q_vel = critic(joint_input(spread_obs(pos, other_vel, lm), act))[..., 0]
    assert not torch.allclose(q_vel[0], q[0], atol=1e-5)  # and with agent 1's velocity, absent from o_0


@pytest.mark.parametrize("pool", POOLS)
def test_parameter_count_does_not_depend_on_the_number_of_agents(pool):
    counts = {n: tuple(count(m) for m in nets(n, pool=pool)) for n in (4, 8, 16)}
    assert counts[4] == counts[8] == counts[16], counts
    assert min(counts[4]) > 0
    with pytest.raises(ValueError, match="pool"):
        nets(4, pool="max")


def test_critic_signatures_agree_on_shared_and_per_owner_rows():
    n = 3
    _, critic = nets(n)
    pos, vel, lm = world(n, m=5, seed=2)
    x = joint_input(spread_obs(pos, vel, lm), torch.rand(5, n, 2))  # [M, in]
    shared = critic(x)  # [N, M, 1]
    assert shared.shape == (n, 5, 1)
    per_owner = critic(x.unsqueeze(0).repeat(n, 1, 1))  # the same rows, materialised per owner
    torch.testing.assert_close(per_owner, shared, atol=1e-6, rtol=1e-6)
    torch.testing.assert_close(critic(x, torch.tensor([2, 0])), shared[[2, 0]])
    with pytest.raises(ValueError, match="one agent per owner"):
        critic(x.unsqueeze(0).repeat(n, 1, 1), torch.tensor([0]))


@pytest.mark.parametrize("pool", POOLS)
def test_masked_entities_are_ignored(pool):
    layout = spread_layout(3)
    gen = torch.Generator().manual_seed(0)
    actor = EntityActor(layout, 2, 16, gen, pool=pool)
    pos, vel, lm = world(3, m=4, seed=3)
    own, ents, _ = layout.split(spread_obs(pos, vel, lm)[None])
    own, ents = own.reshape(1, -1, own.shape[-1]), ents.reshape(1, -1, *ents.shape[-2:])
    mask = torch.ones(ents.shape[:-1], dtype=torch.bool)
    mask[..., 1] = False
    z = actor.encoder(own, ents, mask)
    changed = ents.clone()
    changed[..., 1, :2] += 5.0
    torch.testing.assert_close(actor.encoder(own, changed, mask), z)
    assert not torch.allclose(actor.encoder(own, changed, torch.ones_like(mask)), z)
    empty = actor.encoder(own, ents, torch.zeros_like(mask))  # no entity at all: finite
    assert torch.isfinite(empty).all()


@pytest.mark.parametrize("pool", POOLS)
def test_gradients_reach_every_parameter(pool):
    n = 4
    actor, critic = nets(n, pool=pool)
    pos, vel, lm = world(n, seed=4)
    obs = spread_obs(pos, vel, lm)
    act = actor(obs.transpose(0, 1)).transpose(0, 1)  # [M, N, 2]
    q = critic(joint_input(obs, act))
    q.sum().backward()
    for module in (actor, critic):
        for name, p in module.named_parameters():
            assert p.grad is not None and p.grad.abs().sum() > 0, name


def test_predator_prey_layout_runs_through_both_networks():
    params = TagParams()
    layout = tag_layout(params)
    gen = torch.Generator().manual_seed(0)
    actor, critic = EntityActor(layout, 2, 16, gen), EntityCritic(layout, 2, 16, gen)
    obs = torch.randn(7, params.num_agents, layout.obs_dim)
    assert actor(obs.transpose(0, 1)).shape == (params.num_agents, 7, 2)
    assert critic(joint_input(obs, torch.randn(7, params.num_agents, 2))).shape == (params.num_agents, 7, 1)


def test_the_relational_round_lets_one_entity_see_another_and_keeps_absent_ones_out():
    """After `relate`, entity 0's embedding moves when entity 1 moves (a landmark can tell that an agent holds
    it); entity 0's embedding before it does not; a masked entity moves nothing."""
    gen = torch.Generator().manual_seed(0)
    encoder = EntityEncoder(1, 4, 5, 16, gen, pool="relational")
    ents = torch.randn(1, 6, 3, 5, generator=gen)
    moved = ents.clone()
    moved[..., 1, :] += 2.0
    mask = torch.ones(1, 6, 3, dtype=torch.bool)
    embed = lambda e: encoder.entity(e.reshape(1, -1, 5)).relu().view(1, 6, 3, 16)  # noqa: E731
    torch.testing.assert_close(embed(moved)[..., 0, :], embed(ents)[..., 0, :])
    related, related_moved = encoder.relate(embed(ents), mask, True), encoder.relate(embed(moved), mask, True)
    assert not torch.allclose(related_moved[..., 0, :], related[..., 0, :])
    mask[..., 1] = False
    torch.testing.assert_close(encoder.relate(embed(moved), mask, False)[..., 0, :],
                               encoder.relate(embed(ents), mask, False)[..., 0, :])


def joint_path_q(critic, obs, act, own_act, count=None):
    """The actor step's Q before q_own_action: own_act written into the joint action, the full joint input."""
    n = obs.shape[0]
    joint = torch.where(torch.eye(n, dtype=torch.bool).view(n, 1, n, 1), own_act.unsqueeze(2), act)
    return critic(joint_input(obs, joint), count=count)[..., 0]


@pytest.mark.parametrize("pool", POOLS)
@pytest.mark.parametrize("task", ["spread", "tag"])
def test_q_own_action_gives_the_joint_paths_values_and_gradients(pool, task):
    """The actor step's shortcut (entity slots from the buffer's actions) against the joint path: the same Q and
    the same gradient with respect to the own actions, with and without absent agents."""
    layout = spread_layout(4) if task == "spread" else tag_layout(TagParams())
    n, s = layout.num_agents, 9
    gen = torch.Generator().manual_seed(1)
    critic = EntityCritic(layout, 2, 16, gen, pool=pool)
    obs, act = torch.randn(n, s, n, layout.obs_dim, generator=gen), torch.rand(n, s, n, 2, generator=gen) * 2 - 1
    for count in (None, torch.randint(1, n + 1, (n, s), generator=gen) if task == "spread" else None):
        own_a = (torch.rand(n, s, 2, generator=gen) * 2 - 1).requires_grad_()
        own_b = own_a.detach().clone().requires_grad_()
        q_joint = joint_path_q(critic, obs, act, own_a, count)
        q_own = critic.q_own_action(obs, act, own_b, count)
        torch.testing.assert_close(q_own, q_joint, atol=1e-6, rtol=1e-6)
        q_joint.sum().backward()
        q_own.sum().backward()
        torch.testing.assert_close(own_b.grad, own_a.grad, atol=1e-6, rtol=1e-6)


def test_nearest_entities_is_an_opt_in_that_keeps_the_closest_of_each_kind():
    """k >= E: every entity is kept (the same actions within float tolerance, the entities reordered); k = 1:
    only the nearest landmark and the nearest other agent reach the action, moving a farther one changes nothing."""
    n = 4
    layout = spread_layout(n)
    gen = torch.Generator().manual_seed(0)
    full = EntityActor(layout, 2, 16, gen, out_act=torch.nn.Tanh)
    pos, vel, lm = world(n, seed=6)
    obs = spread_obs(pos, vel, lm).transpose(0, 1)  # [N, M, obs_dim]
    all_kept = EntityActor(layout, 2, 16, gen, out_act=torch.nn.Tanh, nearest=2 * n)
    all_kept.load_state_dict(full.state_dict())
    torch.testing.assert_close(all_kept(obs), full(obs), atol=1e-6, rtol=1e-5)
    one = EntityActor(layout, 2, 16, gen, out_act=torch.nn.Tanh, nearest=1)
    one.load_state_dict(full.state_dict())
    rel = lm[:, None] - pos[:, :, None]  # [M, N, L, 2]: landmark l seen from agent i
    far = np.linalg.norm(rel, axis=-1).argmax(-1)[:, 0]  # agent 0's farthest landmark in each row
    moved = lm.copy()
    moved[np.arange(len(lm)), far] += 0.5 * rel[np.arange(len(lm)), 0, far]  # farther still, along its direction
    moved_obs = spread_obs(pos, vel, moved).transpose(0, 1)
    torch.testing.assert_close(one(moved_obs)[0], one(obs)[0])
    assert not torch.allclose(full(moved_obs)[0], full(obs)[0], atol=1e-5)
    _, critic = nets(n)
    near_critic = EntityCritic(layout, 2, 32, gen, nearest=2 * n)
    near_critic.load_state_dict(critic.state_dict())
    x = joint_input(spread_obs(pos, vel, lm), torch.rand(6, n, 2, generator=gen))
    torch.testing.assert_close(near_critic(x), critic(x), atol=1e-6, rtol=1e-5)


def reference_copy(module):
    """A copy of an entity module on the reference ops (StackedLinear, advanced-indexing views: fused False)."""
    ref = copy.deepcopy(module)
    for m in ref.modules():
        if isinstance(m, EntityEncoder):
            m.fused = False
    return ref


@pytest.mark.parametrize("onednn", [True, False])
def test_dense_is_stacked_linear_and_relu_with_its_gradients(onednn, monkeypatch):
    """The fused layer (oneDNN, or F.linear where a torch build lacks it) against StackedLinear + relu_."""
    if not onednn:
        monkeypatch.setattr(entity_ops, "_onednn", lambda: False)
    gen = torch.Generator().manual_seed(0)
    layer = StackedLinear(1, 6, 16, gen)
    x = torch.randn(1, 40, 6, generator=gen)
    for relu in (True, False):
        xa, xb = x.clone().requires_grad_(), x.clone().requires_grad_()
        out = entity_ops.dense(layer, xa, relu)
        ref = layer(xb).relu() if relu else layer(xb)
        torch.testing.assert_close(out, ref, atol=1e-6, rtol=1e-6)
        grads = torch.autograd.grad((out * ref.detach().cos()).sum(), (xa, layer.weight, layer.bias))
        ref_grads = torch.autograd.grad((ref * ref.detach().cos()).sum(), (xb, layer.weight, layer.bias))
        for g, r in zip(grads, ref_grads, strict=True):
            torch.testing.assert_close(g, r, atol=1e-5, rtol=1e-5)
        with torch.no_grad():
            torch.testing.assert_close(entity_ops.dense(layer, x, relu), ref, atol=1e-6, rtol=1e-6)


@pytest.mark.parametrize("pool", POOLS)
@pytest.mark.parametrize("task", ["spread", "tag"])
def test_the_fused_ops_give_the_reference_ops_numbers_and_gradients(pool, task):
    """The fused entity kernels (entity_ops.dense, CriticViews.gather) against the reference ops: actions, Q (joint
    path and q_own_action) and every parameter's gradient within 1e-5, with and without absent agents."""
    layout = spread_layout(5) if task == "spread" else tag_layout(TagParams())
    n, s = layout.num_agents, 7
    gen = torch.Generator().manual_seed(2)
    actor = EntityActor(layout, 2, 16, gen, out_act=torch.nn.Tanh, pool=pool)
    critic = EntityCritic(layout, 2, 16, gen, pool=pool)
    obs, act = torch.randn(n, s, n, layout.obs_dim, generator=gen), torch.rand(n, s, n, 2, generator=gen) * 2 - 1
    own_obs = obs[torch.arange(n), :, torch.arange(n)]  # [N, S, obs_dim]
    for count in (None, torch.randint(1, n + 1, (n, s), generator=gen) if task == "spread" else None):
        values = []
        for a, c in ((actor, critic), (reference_copy(actor), reference_copy(critic))):
            pi = a(own_obs, count=count)
            q = c(joint_input(obs, act), count=count)[..., 0] + c.q_own_action(obs, act, pi, count)
            (q.square().sum() + pi.sum()).backward()
            values.append([pi, q, *[p.grad for p in (*a.parameters(), *c.parameters())]])
            for p in (*a.parameters(), *c.parameters()):
                p.grad = None
        for new, ref in zip(*values, strict=True):
            torch.testing.assert_close(new, ref, atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize("layout", [spread_layout(4), spread_layout(5, agent_tags=True), tag_layout(TagParams())],
                         ids=["spread", "spread_tags", "tag"])
def test_the_critic_gathers_the_reference_views_bit_for_bit(layout):
    n = layout.num_agents
    views = EntityCritic(layout, 2, 8, torch.Generator().manual_seed(0)).views
    gen = torch.Generator().manual_seed(3)
    obs, act = torch.randn(2, 9, n, layout.obs_dim, generator=gen), torch.randn(2, 9, n, 2, generator=gen)
    agent = torch.randint(0, n, (2, 9), generator=gen)
    for count in (None, torch.randint(1, n + 1, (2, 9), generator=gen)):
        for new, ref in zip(views.gather(obs, act, agent, count), views.reference(obs, act, agent, count),
                            strict=True):
            assert torch.equal(new, ref)

"""The permuted control on LaBER: under `teams.<team>.priority.difficulty_transform = "permuted"` a
LaBER agent picks its minibatch with its candidates' fresh |δ| shuffled across them by a permutation the buffer
draws from its `control_rng` (cmcl.replay.rules.laber.candidate_orders). Here: the manipulation check on the pick,
the permutations restored on resume, and nothing drawn without the control. The two runners' agreement under the
control is in tests/test_agreement.py."""

import copy

import numpy as np
import pytest

from cmcl.config import load_config
from cmcl.learners.network_steps import choose_minibatch
from cmcl.replay.buffer_steps import sample_owner_batches
from cmcl.replay.priority import EPS_P
from cmcl.replay.rules.laber import CANDIDATES, candidate_orders, select_candidates
from cmcl.replay.snapshot import rng_state
from cmcl.system import layout_of
from tests.test_replay_storage import N, filled

pytestmark = pytest.mark.filterwarnings("error")
B = 16  # picked rows per owner and minibatch (m·B = 64 candidates)
ALL = (True,) * N


class RewardCritic:
    """A critic stub: the |δ| of a row is |r| of the row's owner, a fixed hardness per row, so that a pick by |δ|
    is informative about the row (choose_minibatch calls only `td_abs`)."""

    def td_abs(self, minibatch: dict[str, np.ndarray]) -> np.ndarray:
        """minibatch rew [N, S, N] -> |r| of each owner's own column, float64[N, S]."""
        n = minibatch["rew"].shape[0]
        return np.abs(minibatch["rew"][np.arange(n), :, np.arange(n)])


def own_abs_rew(rew: np.ndarray) -> np.ndarray:
    """|r| of each owner's own column of one minibatch's rows rew [N, S, N] -> [N, S]."""
    return RewardCritic().td_abs({"rew": rew})


def laber_picks(transform: str, count: int = 300) -> dict[str, np.ndarray]:
    """`count` LaBER minibatches of a filled buffer under `transform`, picked by `RewardCritic`: the candidates'
    own |r| [count, N, m·B], the picked rows' [count, N, B], the priority each pick saw (mean(p) / weight) and the
    batch's slots and select_u."""
    rb = filled(capacity=300, episodes=10, algorithms="laber", difficulty_transform=transform, control_seed=4)
    rngs = [np.random.default_rng(i) for i in range(N)]
    batch = sample_owner_batches(rb, count, B, rngs, [0.0] * N, CANDIDATES, (), (transform == "permuted",) * N)
    candidates = np.stack([own_abs_rew(batch.rows["rew"][i]) for i in range(count)])  # [count, N, m·B]
    picked, seen = [], []
    for i in range(count):
        minibatch, _, _ = choose_minibatch(RewardCritic(), batch, i, True, ALL, select_candidates)
        picked.append(own_abs_rew(minibatch["rew"]))
        p = candidates[i] + EPS_P  # as choose_minibatch adds it
        seen.append(p.mean(1, keepdims=True) / minibatch["is_weights"])
    return {"candidates": candidates, "picked": np.stack(picked), "seen": np.stack(seen), "slots": batch.slots,
            "select_u": batch.select_u, "order": batch.select_order}


def test_under_the_control_the_pick_carries_no_information_about_the_rows_but_keeps_their_priorities():
    """Manipulation check: without the control the picked rows are the hard ones (mean |δ| well above the
    candidates'); under it, their mean |δ| is the candidates' within sampling error, while the priorities the picks
    saw (hence the IS weights) are distributed as without it. The candidates and the numbers to pick with are the
    same draws (the orders come from the control's own generator)."""
    rule, control = laber_picks("none"), laber_picks("permuted")
    np.testing.assert_array_equal(rule["slots"], control["slots"])
    np.testing.assert_array_equal(rule["select_u"], control["select_u"])
    assert rule["order"] is None and control["order"].shape == (300, N, CANDIDATES * B)
    mean = control["candidates"].mean()
    assert rule["picked"].mean() > mean + 0.3  # |r| of N(0, 1): E|r| = 0.80, the pick ∝ |r|: E r² / E|r| = 1.25
    assert abs(control["picked"].mean() - mean) < 0.03
    for agent in range(N):  # per agent, too
        assert abs(control["picked"][:, agent].mean() - control["candidates"][:, agent].mean()) < 0.05
    assert abs(control["seen"].mean() - rule["seen"].mean()) < 0.03
    assert abs(control["seen"].std() - rule["seen"].std()) < 0.03


def test_an_identity_order_is_the_rule_and_an_order_must_be_a_permutation():
    rng = np.random.default_rng(0)
    p, u = rng.exponential(1.0, (2, 12)) + 0.01, rng.random((2, 5))
    idx, w = select_candidates(p, u)
    same = select_candidates(p, u, np.broadcast_to(np.arange(12), (2, 12)))
    np.testing.assert_array_equal(idx, same[0])
    np.testing.assert_array_equal(w, same[1])
    order = candidate_orders(np.array([True, False]), 12, np.random.default_rng(1))
    assert sorted(order[0]) == list(range(12)) and list(order[1]) == list(range(12))
    shuffled_idx, shuffled_w = select_candidates(p, u, order)
    np.testing.assert_array_equal(shuffled_idx[1], idx[1])
    np.testing.assert_allclose(shuffled_w[0], p[0].mean() / p[0][order[0]][shuffled_idx[0]], rtol=1e-6)
    with pytest.raises(ValueError, match="permutation"):
        select_candidates(p, u, np.zeros((2, 12), np.int64))
    with pytest.raises(ValueError, match="permutation"):
        select_candidates(p, u, order[:, :6])


def test_only_the_controls_laber_agents_draw_and_only_from_the_control_generator():
    """No agent marked (or m = 1): no order and not one draw from the control's generator; marked agents get a
    permutation each, the others the identity; the samplers' streams advance as without the control."""
    rb = filled(capacity=300, episodes=10, algorithms=["laber", "laber", "per"],
                difficulty_transform=["permuted", "none", "permuted"])
    before = rng_state(rb.control_rng)
    plain = [np.random.default_rng(i) for i in range(N)]
    batch = sample_owner_batches(rb, 2, B, plain, [0.0] * N, CANDIDATES, (), (False,) * N)
    assert batch.select_order is None and rng_state(rb.control_rng) == before
    batch = sample_owner_batches(rb, 2, B, plain, [0.0] * N, 1, (), (True, False, False))
    assert batch.select_order is None and rng_state(rb.control_rng) == before
    marked = [np.random.default_rng(i) for i in range(N)]
    unmarked = copy.deepcopy(marked)
    batch = sample_owner_batches(rb, 2, B, marked, [0.0] * N, CANDIDATES, (), (True, False, False))
    sample_owner_batches(rb, 2, B, unmarked, [0.0] * N, CANDIDATES)
    assert [g.bit_generator.state for g in marked] == [g.bit_generator.state for g in unmarked]
    assert rng_state(rb.control_rng) != before
    order = batch.select_order
    assert order.shape == (2, N, CANDIDATES * B) and order.dtype == np.int64
    np.testing.assert_array_equal(np.sort(order[:, 0], axis=-1), np.broadcast_to(np.arange(CANDIDATES * B), (2, 64)))
    assert (order[:, 0] != np.arange(CANDIDATES * B)).any()
    np.testing.assert_array_equal(order[:, 1:], np.broadcast_to(np.arange(CANDIDATES * B), (2, N - 1, 64)))


def test_the_controls_permutations_are_restored_on_resume_and_drawn_alike_one_minibatch_at_a_time():
    """The buffer's state carries the control's generator: a buffer loaded from it (built with another seed) draws
    the same next batch, orders included; n minibatches in one call are n calls of one (the replay server's
    `service.updates_per_call`)."""
    kw = {"capacity": 300, "episodes": 10, "algorithms": "laber", "difficulty_transform": "permuted"}
    rb = filled(control_seed=5, **kw)
    rngs = [np.random.default_rng(i) for i in range(N)]
    sample_owner_batches(rb, 2, B, rngs, [0.0] * N, CANDIDATES, (), ALL)
    state, saved = rb.state_dict(), copy.deepcopy(rngs)
    again = filled(control_seed=99, **kw)
    again.load_state_dict(state)
    after = sample_owner_batches(rb, 3, B, rngs, [0.0] * N, CANDIDATES, (), ALL)
    one_at_a_time = [sample_owner_batches(again, 1, B, saved, [0.0] * N, CANDIDATES, (), ALL) for _ in range(3)]
    resumed = np.concatenate([b.select_order for b in one_at_a_time])
    np.testing.assert_array_equal(after.select_order, resumed)
    np.testing.assert_array_equal(after.slots, np.concatenate([b.slots for b in one_at_a_time]))
    fresh = filled(control_seed=5, **kw)  # not resumed: the run's first orders again, not its next ones
    first = sample_owner_batches(fresh, 3, B, [np.random.default_rng(i) for i in range(N)], [0.0] * N, CANDIDATES,
                                 (), ALL)
    assert not np.array_equal(first.select_order, after.select_order)


@pytest.mark.parametrize(("algorithm", "transform", "marked"), [
    ("laber", "permuted", True), ("laber", "none", False), ("laber", "reversed", False), ("per", "permuted", False)])
def test_the_layout_marks_the_laber_agents_under_the_permuted_control(algorithm, transform, marked):
    config = load_config(None, [f"teams.agent.algorithm={algorithm}",
                                f"teams.agent.priority.difficulty_transform={transform}"])
    layout = layout_of(config)
    assert layout.permuted_select == (marked,) * layout.num_agents


@pytest.mark.parametrize("transform", ["permuted", "none"])
def test_the_replay_servers_sample_draws_the_controls_orders_only_under_the_control(transform):
    """The replay server's `sample` (the learner's batches of both runners: the inline runner calls the same server
    in-process) draws each minibatch's orders from its buffer's control generator; without the control it draws
    none."""
    from services.roles.replay_server import ReplayServer
    from services.roles.rollout import RolloutWorker
    from tests.in_process import in_process_config

    cfg = in_process_config("laber", service={"score_rows_per_call": 360})
    cfg["teams"]["agent"]["priority"]["difficulty_transform"] = transform
    server, worker = ReplayServer(cfg), RolloutWorker(cfg, 0, 0)
    for _ in range(3):
        server.insert(worker.rollout(None)[0])
    before = rng_state(server.replay.control_rng)
    batch, _ = server.sample(1)
    assert (rng_state(server.replay.control_rng) != before) == (transform == "permuted")
    assert (batch.select_order is None) == (transform == "none")

"""Replay storage and ReplayBuffer (ALGORITHM.md §3.1, §3.6, §7 properties 8, 10, 11, 16, 18–20, 22)."""

import numpy as np
import pytest
from scipy import stats

from cmcl.io import codec
from cmcl.replay.buffer import ReplayBuffer, ReplayNotReady
from cmcl.replay.curriculum import CurriculumSchedule
from cmcl.replay.priority import EPS_P
from cmcl.replay.sampler import BACKENDS

pytestmark = pytest.mark.filterwarnings("error")
N, OD, AD = 3, 4, 2


def chunk(t, episode, rng, n=N):
    """One chunk of t transitions: (obs, act, rew, next_obs, done, episode)."""
    ep = np.broadcast_to(np.asarray(episode, np.int64), (t,))
    return (rng.normal(size=(t, n, OD)), rng.uniform(-1, 1, (t, n, AD)), rng.normal(size=(t, n)),
            rng.normal(size=(t, n, OD)), np.zeros(t), ep)


def filled(capacity=300, episodes=12, ep_len=30, seed=0, **kw):
    rb = ReplayBuffer(capacity=capacity, n_agents=N, obs_dim=OD, act_dim=AD, **kw)
    rng = np.random.default_rng(seed)
    for e in range(episodes):
        rb.add(*chunk(ep_len, e, rng))
    return rb


def test_add_layout_ids_generations_folds():
    rb = ReplayBuffer(capacity=10, n_agents=N, obs_dim=OD, act_dim=AD, n_folds=3)
    rng = np.random.default_rng(0)
    c = chunk(4, 7, rng)
    slots = rb.add(*c, policy_version=5)
    assert slots.tolist() == [0, 1, 2, 3] and rb.size == 4
    row = rb.get(slots)
    assert row["obs"].dtype == np.float32 and row["obs"].shape == (4, N, OD)
    assert np.allclose(row["obs"], c[0]) and np.allclose(row["act"], c[1])
    assert row["fold"].tolist() == [1] * 4 and row["policy_version"].tolist() == [5] * 4
    assert row["generation"].tolist() == [1] * 4 and row["id"].tolist() == [0, 1, 2, 3]
    slots = rb.add(*chunk(8, 8, rng))  # wraps: slots 4..9, 0, 1
    assert slots.tolist() == [4, 5, 6, 7, 8, 9, 0, 1] and rb.size == 10
    g = rb.get(np.arange(10))
    assert g["generation"].tolist() == [2, 2, 1, 1, 1, 1, 1, 1, 1, 1]
    assert g["id"].tolist() == [10, 11, 2, 3, 4, 5, 6, 7, 8, 9]
    assert np.array_equal(g["id"] % 10, np.arange(10))


def test_chunk_longer_than_capacity_keeps_last():
    rb = ReplayBuffer(capacity=5, n_agents=N, obs_dim=OD, act_dim=AD)
    rng = np.random.default_rng(1)
    rb.add(*chunk(2, 0, rng))
    c = chunk(12, 1, rng)
    slots = rb.add(*c)
    assert slots[:7].tolist() == [-1] * 7 and sorted(slots[7:].tolist()) == list(range(5))
    got = rb.get(slots[7:])
    assert np.allclose(got["obs"], c[0][7:]) and got["id"].tolist() == list(range(9, 14))
    assert rb.storage.next_id == 14 and rb.size == 5


def test_fold_balance_after_wraparound():  # property 10
    ep_len, k = 30, 5
    rb = ReplayBuffer(capacity=5000, n_agents=1, obs_dim=1, act_dim=1, n_folds=k)
    z3, z2 = np.zeros((ep_len, 1, 1)), np.zeros((ep_len, 1))
    for e in range(800):  # 24 000 transitions, ~5 wraparounds
        rb.add(z3, z3, z2, z3, np.zeros(ep_len), np.full(ep_len, e))
        if e % 97 == 0 or e == 799:
            counts = rb.storage.fold_counts()
            assert counts.sum() == rb.size
            if rb.size == 5000:  # 166 whole episodes + one partial (5000 mod 30 = 20)
                assert counts.max() - counts.min() <= ep_len + 5000 % ep_len
    full_eps = np.bincount(np.unique(rb.get(rb.valid_slots())["episode"]) % k, minlength=k)
    assert full_eps.max() - full_eps.min() <= 1


def test_fold_slots_only_own_fold():  # property 11 (the storage side)
    rb = filled()
    parts = [rb.fold_slots(k) for k in range(5)]
    for k, s in enumerate(parts):
        assert np.all(rb.get(s)["fold"] == k)
        assert np.all(rb.get(s)["episode"] % 5 == k)
    assert np.array_equal(np.sort(np.concatenate(parts)), rb.valid_slots())
    with pytest.raises(ValueError, match="k must"):
        rb.fold_slots(5)


@pytest.mark.parametrize("field, bad, match", [
    (0, np.zeros((4, N, OD + 1)), r"obs has shape \(4, 3, 5\)"),
    (1, np.zeros((4, N, AD), dtype=object), "act must be a real numeric array"),
    (2, np.array([[0, 1, np.nan]] * 4), "rew must be finite"),
    (3, np.full((4, N, OD), 1e39), "next_obs value .* does not fit in float32"),
    (4, np.full(4, 2.0), "done must lie in"),
    (5, np.full(4, 1.5), "episode must be integers"),
    (5, np.full(4, -1), "episode must be >= 0"),
    (2, np.zeros((4, N + 1)), r"rew has shape \(4, 4\), expected \(4, 3\)"),
])
def test_add_rejects_bad_input_and_stores_nothing(field, bad, match):
    rb = filled(capacity=50, episodes=2)
    before = rb.state_dict()
    args = list(chunk(4, 9, np.random.default_rng(3)))
    args[field] = bad
    with pytest.raises(ValueError, match=match):
        rb.add(*args)
    after = rb.state_dict()
    assert rb.size == before["storage"]["size"] and after["storage"]["next_id"] == before["storage"]["next_id"]
    assert np.array_equal(after["storage"]["obs"], before["storage"]["obs"])
    with pytest.raises(ValueError, match="policy_version"):
        rb.add(*chunk(4, 9, np.random.default_rng(3)), policy_version=-2)


def test_update_scores_drops_stale():
    rb = filled(capacity=60, episodes=2)  # slots 0..59, generation 1
    slots = np.arange(0, 60, 6)
    gens = rb.generations(slots)
    rb.add(*chunk(30, 2, np.random.default_rng(5)))  # overwrites slots 0..29
    vals = np.arange(10 * N, dtype=np.float32).reshape(10, N)
    accepted = rb.update_scores("difficulty", slots, gens, vals)
    assert accepted == 5 and rb.storage.last_dropped == 5 and rb.storage.stale_dropped_total == 5
    assert np.all(rb.storage.scores["difficulty"][slots[:5]] == 0)
    assert np.array_equal(rb.storage.scores["difficulty"][slots[5:]], vals[5:])
    assert rb.update_scores("curiosity", [31, 32], rb.generations([31, 32]), [1.0, 2.0], agents=[2]) == 2
    assert rb.storage.scores["curiosity"][[31, 32], 2].tolist() == [1.0, 2.0]
    empty = ReplayBuffer(capacity=10, n_agents=N, obs_dim=OD, act_dim=AD)
    assert empty.update_scores("td_abs", [3], [0], np.ones((1, N))) == 0  # never-written slot
    for kwargs, match in [({"values": -np.ones((10, N))}, "values must be >= 0"),
                          ({"values": np.ones((10, N - 1))}, "values has shape"),
                          ({"column": "reward"}, "column"), ({"agents": [0, 0, 1]}, "agents")]:
        args = {"column": "difficulty", "slots": slots, "generations": gens, "values": vals, **kwargs}
        with pytest.raises(ValueError, match=match):
            rb.update_scores(**args)


def test_overwrite_resets_scores():
    rb = filled(capacity=30, episodes=1)
    rb.update_scores("difficulty", rb.valid_slots(), rb.generations(rb.valid_slots()), np.ones((30, N)))
    rb.add(*chunk(10, 1, np.random.default_rng(0)))
    assert np.all(rb.storage.scores["difficulty"][:10] == 0) and not rb.storage.scored["difficulty"][:10].any()
    assert np.all(rb.storage.scored["difficulty"][10:])


def test_uniform_mode_chi_square_and_not_ready():  # property 16
    rb = ReplayBuffer(capacity=100, n_agents=N, obs_dim=OD, act_dim=AD, min_size=40)
    rng = np.random.default_rng(0)
    rb.add(*chunk(39, 0, rng))
    with pytest.raises(ReplayNotReady, match="needs at least 40"):
        rb.sample(0, 8, rng)
    rb.add(*chunk(11, 1, rng))
    slots, w = rb.sample(1, 100_000, np.random.default_rng(1))
    assert np.all(w == 1) and slots.max() < 50
    assert stats.chisquare(np.bincount(slots, minlength=50)).pvalue > 1e-3


def _scored_buffer(backend="cdf", algorithms=("acl", "cmcl", "maddpg"), **kw):
    rb = filled(capacity=300, episodes=10, algorithms=list(algorithms), backend=backend, **kw)
    rng = np.random.default_rng(11)
    s = rb.valid_slots()
    rb.update_scores("difficulty", s, rb.generations(s), rng.exponential(1.0, (s.size, N)))
    rb.update_scores("curiosity", s, rb.generations(s), rng.exponential(0.05, (s.size, N)))
    return rb


@pytest.mark.parametrize("backend", BACKENDS)
def test_eta_zero_cmcl_equals_acl_and_ci_range(backend):  # property 8
    rb = _scored_buffer(backend, algorithms=("acl", "cmcl", "cmcl"), eta=[0.5, 0.0, 0.7])
    rb.update_scores("difficulty", rb.valid_slots(), rb.generations(rb.valid_slots()),
                     np.repeat(rb.storage.scores["difficulty"][:300, :1], N, axis=1))
    d = rb.recompute_priorities(0.3, details=True)
    s = rb.valid_slots()
    assert np.array_equal(rb.probabilities(0, s), rb.probabilities(1, s))
    ci = d["priority"] - EPS_P
    assert ci.min() >= -1e-12 and ci[:, 2].max() <= 1.7 and ci[:, 2].max() > 1.0


def test_unscored_rows_get_floor():
    rb = _scored_buffer()
    new = rb.add(*chunk(30, 10, np.random.default_rng(2)))  # overwrites slots 0..29, unscored
    d = rb.recompute_priorities(0.2, details=True)
    assert np.all(d["priority"][new] == EPS_P) and not d["scored"][new].any()
    assert np.all(d["scored"][30:])


@pytest.mark.parametrize("backend", BACKENDS)
def test_priority_recompute_follows_lambda(backend):  # property 22
    rb = _scored_buffer(backend, algorithms=("acl", "acl", "maddpg"))
    c = rb.storage.scores["difficulty"][:300, 0]
    j = int(np.argsort(c)[-30])  # a hard sample: ĉ_j well above 2λ_0
    c_hat_j = np.sum(c < c[j]) / (c.size - 1)  # the default rank normalisation (A1, revised)
    assert c_hat_j > 0.3
    assert rb.alpha[0] == 1.0  # the default α_s of ACL / CMCL (A8, revised)
    sch = CurriculumSchedule(lam0=0.1, stride=0.01, warmup_steps=0)
    rb.recompute_priorities(sch.lam)
    floor_prob = EPS_P / np.sum(rb.sampling[0].priorities[:300])
    assert rb.probabilities(0, [j])[0] == pytest.approx(floor_prob)
    probs = []
    while sch.lam < 1.0:
        sch.advance(1)
        rb.recompute_priorities(sch.lam)  # recomputed after every λ change
        probs.append((sch.lam, rb.probabilities(0, [j])[0]))
    below = [p for lam, p in probs if lam < c_hat_j / 2 - 1e-9]
    above = [p for lam, p in probs if lam > c_hat_j / 2 + 0.02]
    assert max(below) < 1e-3 / 300 and min(above) > 100 * max(below)
    with pytest.raises(ValueError, match="lam"):
        rb.recompute_priorities(1.5)


@pytest.mark.parametrize("backend", BACKENDS)
def test_per_max_priority_rule(backend):  # property 19
    rb = filled(capacity=100, episodes=1, algorithms="per", backend=backend, alpha=1.0)
    assert np.all(rb.sampling[0].priorities[:30] == 1.0) and rb.sampling[0].max_priority == 1.0
    acc = rb.update_priorities(0, [0, 1, 2], [3.0, -0.5, 0.0])
    assert acc == 3
    assert rb.sampling[0].priorities[:3].tolist() == pytest.approx([3.0 + EPS_P, 0.5 + EPS_P, EPS_P])
    assert rb.sampling[0].max_priority == pytest.approx(3.0 + EPS_P) and rb.sampling[1].max_priority == 1.0
    new = rb.add(*chunk(5, 1, np.random.default_rng(0)))
    assert rb.sampling[0].priorities[new].tolist() == pytest.approx([3.0 + EPS_P] * 5)
    assert rb.sampling[1].priorities[new].tolist() == [1.0] * 5
    assert rb.storage.scores["td_abs"][[0, 1], 0].tolist() == [3.0, 0.5]
    old_gen = rb.generations([0])
    rb.add(*chunk(70, 2, np.random.default_rng(1)))  # wraps over slot 0
    assert rb.update_priorities(0, [0], [100.0], generations=old_gen) == 0
    assert rb.sampling[0].max_priority == pytest.approx(3.0 + EPS_P)
    with pytest.raises(ValueError, match="'per' agent"):
        filled(capacity=50, episodes=1).update_priorities(0, [0], [1.0])


def test_is_weights_in_buffer():  # property 18
    rb = filled(capacity=200, episodes=5, algorithms=["per", "per", "maddpg"], is_beta=0.4)
    rng = np.random.default_rng(0)
    rb.update_priorities(0, rb.valid_slots(), rng.exponential(1.0, 150))
    _, w = rb.sample(0, 128, rng)
    assert w.max() == 1.0 and np.all(w <= 1) and w.min() < 1
    _, w1 = rb.sample(1, 128, rng)  # all priorities equal -> weights all 1
    assert np.all(w1 == 1)
    _, w0 = rb.sample(0, 128, rng, beta=0.0)
    assert np.all(w0 == 1)


def test_per_agent_samplers_independent():  # property 20
    rb = _scored_buffer(algorithms=("cmcl", "cmcl", "maddpg"))
    rb.recompute_priorities(0.1)
    s, w = rb.sample_all(128, [np.random.default_rng(i) for i in range(N)])
    assert s.shape == (N, 128) and w.shape == (N, 128)
    assert not np.array_equal(np.sort(s[0]), np.sort(s[1]))
    prey = rb.sample(2, 60_000, np.random.default_rng(9))[0]  # predators use CMCL, prey uniform
    assert stats.chisquare(np.bincount(prey, minlength=300)).pvalue > 1e-3
    pred = rb.sample(0, 60_000, np.random.default_rng(9))[0]
    assert stats.chisquare(np.bincount(pred, minlength=300)).pvalue < 1e-6
    a = rb.sample(0, 50, np.random.default_rng(4))[0]
    rb.sample(1, 50, np.random.default_rng(5))
    assert np.array_equal(a, rb.sample(0, 50, np.random.default_rng(4))[0])


def test_sampling_chosen_once_per_algorithm():
    rb = filled(capacity=300, episodes=10, algorithms=["per", "acl", "maddpg"])
    assert [s.name for s in rb.sampling] == ["per", "acl", "uniform"] and [a for a, _ in rb.curriculum] == [1]
    assert np.all(rb.sampling[0].priorities[:300] == 1.0) and np.all(rb.sampling[1].priorities[:300] == EPS_P)
    with pytest.raises(ValueError, match="algorithm"):
        filled(capacity=300, episodes=1, algorithms=["per", "sorted", "acl"])
    with pytest.raises(ValueError, match="algorithm"):
        filled(capacity=300, episodes=1, algorithms="uniform")  # the sampling's name, not an algorithm
    with pytest.raises(ValueError, match="one entry per agent"):
        filled(capacity=300, episodes=1, algorithms=["per", "acl"])


@pytest.mark.parametrize("backend", BACKENDS)
def test_state_dict_round_trip_through_codec(backend):
    rb = _scored_buffer(backend, algorithms=("per", "cmcl", "maddpg"), is_beta=[0.5, 0.0, 0.0])
    rb.update_priorities(0, [1, 2, 3], [4.0, 2.0, 0.1])
    rb.add(*chunk(45, 10, np.random.default_rng(3)))
    rb.recompute_priorities(0.4)
    snap = codec.decode_snapshot(codec.encode_snapshot(rb.state_dict()))
    other = ReplayBuffer(capacity=300, n_agents=N, obs_dim=OD, act_dim=AD, algorithms=["per", "cmcl", "maddpg"],
                         backend=backend, is_beta=[0.5, 0.0, 0.0])
    other.load_state_dict(snap)
    assert other.lam == 0.4 and other.sampling[0].max_priority == rb.sampling[0].max_priority
    s = rb.valid_slots()
    for a in range(N):
        assert np.array_equal(other.probabilities(a, s), rb.probabilities(a, s))
        x, y = rb.sample(a, 64, np.random.default_rng(a)), other.sample(a, 64, np.random.default_rng(a))
        assert np.array_equal(x[0], y[0]) and np.array_equal(x[1], y[1])
    for k, v in rb.get(s).items():
        assert np.array_equal(other.get(s)[k], v)
    assert other.storage.next_id == rb.storage.next_id
    new_a, new_b = rb.add(*chunk(3, 11, np.random.default_rng(4))), other.add(*chunk(3, 11, np.random.default_rng(4)))
    assert np.array_equal(new_a, new_b)


def test_load_state_dict_rejects_and_leaves_buffer_untouched():
    rb = _scored_buffer(algorithms=("acl", "acl", "maddpg"))
    rb.recompute_priorities(0.3)
    good = rb.state_dict()
    probs = rb.probabilities(0, rb.valid_slots())
    with pytest.raises(ValueError, match="algorithms"):
        ReplayBuffer(capacity=300, n_agents=N, obs_dim=OD, act_dim=AD, algorithms="per").load_state_dict(good)
    bad = rb.state_dict()
    bad["storage"]["fold"] = (bad["storage"]["fold"] + 1) % 5
    with pytest.raises(ValueError, match="fold"):
        rb.load_state_dict(bad)
    bad = rb.state_dict()
    bad["sampling"]["0"]["priorities"][5] = np.nan
    with pytest.raises(ValueError, match="finite"):
        rb.load_state_dict(bad)
    bad = rb.state_dict()
    bad["storage"]["obs"] = bad["storage"]["obs"][:, :, :2]
    with pytest.raises(ValueError, match="obs has shape"):
        rb.load_state_dict(bad)
    small = _scored_buffer(algorithms=("acl", "acl", "maddpg"))
    small.recompute_priorities(0.3)
    bad = small.state_dict()
    for key in ("obs", "act", "rew", "next_obs", "done", "id", "episode", "fold", "generation", "policy_version"):
        bad["storage"][key] = bad["storage"][key][:100]
    for group in ("scores", "scored"):
        bad["storage"][group] = {k: v[:100] for k, v in bad["storage"][group].items()}
    bad["storage"]["size"] = bad["storage"]["next_id"] = 100
    with pytest.raises(ValueError, match="beyond size 100"):
        rb.load_state_dict(bad)
    bad = rb.state_dict()
    bad["lam"] = 3.0
    with pytest.raises(ValueError, match="lam in state"):
        rb.load_state_dict(bad)
    bad = rb.state_dict()
    bad["storage"]["obs"] = bad["storage"]["obs"][:, :, :2]
    with pytest.raises(ValueError, match="obs has shape"):
        rb.load_state_dict(bad)
    assert np.array_equal(rb.probabilities(0, rb.valid_slots()), probs)
    assert rb.state_dict()["storage"]["next_id"] == good["storage"]["next_id"]


def test_sample_argument_errors():
    rb = filled(capacity=50, episodes=1)
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="agent"):
        rb.sample(N, 4, rng)
    with pytest.raises(ValueError, match="batch_size"):
        rb.sample(0, 0, rng)
    with pytest.raises(ValueError, match="slots"):
        rb.get([30])
    with pytest.raises(ValueError, match="backend"):
        ReplayBuffer(n_agents=1, obs_dim=1, act_dim=1, backend="tree")


def test_loads_a_format_1_snapshot():
    """A buffer snapshotted before the sampling distributions were objects (format 1: "modes" with "uniform",
    "samplers", one "max_priority" array; written by that version) loads and samples as it did."""
    from pathlib import Path

    old = codec.read_snapshot(Path(__file__).parent / "fixtures" / "replay_format1.msgpack")
    assert "format" not in old["replay"] and old["replay"]["modes"]["2"] == "uniform"
    rb = ReplayBuffer(capacity=60, n_agents=N, obs_dim=2, act_dim=1, algorithms=["per", "cmcl", "maddpg"],
                      alpha=[0.6, 1.0, 1.0])
    rb.load_state_dict(old["replay"])
    s = rb.valid_slots()
    assert rb.lam == 0.35 and rb.sampling[0].max_priority == old["max_priority"][0]
    for a in range(N):
        assert np.array_equal(rb.probabilities(a, s), old["probabilities"][a])
        assert np.array_equal(rb.sample(a, 16, np.random.default_rng(a), beta=0.4)[0], old["draws"][a])
    assert rb.state_dict()["format"] == 2
    done = np.asarray(old["replay"]["storage"]["done"])  # one per row then: every agent's, per agent now
    assert done.shape == (60,) and np.array_equal(rb.storage.done[:60], np.repeat(done[:, None], N, 1))
    with pytest.raises(ValueError, match="format 3"):
        rb.load_state_dict({**rb.state_dict(), "format": 3})

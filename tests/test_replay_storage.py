"""Replay storage: rows in (layout, ids, generations, folds, input checks), score columns (stale updates dropped,
reset on overwrite) and snapshots out and back (ALGORITHM.md §3.1, §7 properties 10, 11). Sampling from the
stored rows: tests/test_replay_sampling.py."""

import numpy as np
import pytest

from cmcl.io import codec
from cmcl.replay.sampler import BACKENDS
from tests.buffers import make_buffer

pytestmark = pytest.mark.filterwarnings("error")
N, OD, AD = 3, 4, 2


def chunk(t, episode, rng, n=N):
    """One chunk of t transitions: (obs, act, rew, next_obs, done, episode)."""
    ep = np.broadcast_to(np.asarray(episode, np.int64), (t,))
    return (rng.normal(size=(t, n, OD)), rng.uniform(-1, 1, (t, n, AD)), rng.normal(size=(t, n)),
            rng.normal(size=(t, n, OD)), np.zeros(t), ep)


def filled(capacity=300, episodes=12, ep_len=30, seed=0, **kw):
    """A ReplayBuffer of N agents (`kw`: its other arguments) holding `episodes` random episodes of `ep_len` steps."""
    rb = make_buffer(capacity=capacity, n_agents=N, obs_dim=OD, act_dim=AD, **kw)
    rng = np.random.default_rng(seed)
    for e in range(episodes):
        rb.add(*chunk(ep_len, e, rng))
    return rb


def scored_buffer(backend="cdf", algorithms=("acl", "cmcl", "maddpg"), **kw):
    """`filled` (10 episodes, 300 rows) with one sampling per agent and random difficulty and curiosity scores."""
    rb = filled(capacity=300, episodes=10, algorithms=list(algorithms), backend=backend, **kw)
    rng = np.random.default_rng(11)
    s = rb.valid_slots()
    rb.update_scores("difficulty", s, rb.generations(s), rng.exponential(1.0, (s.size, N)))
    rb.update_scores("curiosity", s, rb.generations(s), rng.exponential(0.05, (s.size, N)))
    return rb


def test_add_layout_ids_generations_folds():
    rb = make_buffer(capacity=10, n_agents=N, obs_dim=OD, act_dim=AD, n_folds=3)
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
    rb = make_buffer(capacity=5, n_agents=N, obs_dim=OD, act_dim=AD)
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
    rb = make_buffer(capacity=5000, n_agents=1, obs_dim=1, act_dim=1, n_folds=k)
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
    empty = make_buffer(capacity=10, n_agents=N, obs_dim=OD, act_dim=AD)
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


@pytest.mark.parametrize("backend", BACKENDS)
def test_state_dict_round_trip_through_codec(backend):
    rb = scored_buffer(backend, algorithms=("per", "cmcl", "maddpg"))
    rb.update_priorities(0, [1, 2, 3], [4.0, 2.0, 0.1])
    rb.add(*chunk(45, 10, np.random.default_rng(3)))
    rb.recompute_priorities(0.4)
    snap = codec.decode_snapshot(codec.encode_snapshot(rb.state_dict()))
    other = make_buffer(capacity=300, n_agents=N, obs_dim=OD, act_dim=AD, algorithms=["per", "cmcl", "maddpg"],
                         backend=backend)
    other.load_state_dict(snap)
    assert other.lam == 0.4 and other.sampling[0].max_priority == rb.sampling[0].max_priority
    s = rb.valid_slots()
    for a in range(N):
        assert np.array_equal(other.probabilities(a, s), rb.probabilities(a, s))
        beta = [0.5, 0.0, 0.0][a]
        x, y = rb.sample(a, 64, np.random.default_rng(a), beta), other.sample(a, 64, np.random.default_rng(a), beta)
        assert np.array_equal(x[0], y[0]) and np.array_equal(x[1], y[1])
    for k, v in rb.get(s).items():
        assert np.array_equal(other.get(s)[k], v)
    assert other.storage.next_id == rb.storage.next_id
    new_a, new_b = rb.add(*chunk(3, 11, np.random.default_rng(4))), other.add(*chunk(3, 11, np.random.default_rng(4)))
    assert np.array_equal(new_a, new_b)


def test_load_state_dict_rejects_and_leaves_buffer_untouched():
    rb = scored_buffer(algorithms=("acl", "acl", "maddpg"))
    rb.recompute_priorities(0.3)
    good = rb.state_dict()
    probs = rb.probabilities(0, rb.valid_slots())
    with pytest.raises(ValueError, match="algorithms"):
        make_buffer(capacity=300, n_agents=N, obs_dim=OD, act_dim=AD, algorithms="per").load_state_dict(good)
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
    small = scored_buffer(algorithms=("acl", "acl", "maddpg"))
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
    assert np.array_equal(rb.probabilities(0, rb.valid_slots()), probs)
    assert rb.state_dict()["storage"]["next_id"] == good["storage"]["next_id"]


def test_a_snapshot_of_an_older_format_is_refused_in_one_line_naming_the_last_commit_that_reads_it():
    """A buffer snapshotted before the sampling distributions were objects (format 1: "modes", "samplers", one
    "max_priority" array; written by that version), or one of format 2 without a field this version writes: refused
    in one line naming the format or the field and the commit that reads it; the buffer is left as it was."""
    from pathlib import Path

    from cmcl.replay.snapshot import LAST_READER

    old = codec.read_snapshot(Path(__file__).parent / "fixtures" / "replay_format1.msgpack")
    rb = make_buffer(capacity=60, n_agents=N, obs_dim=OD, act_dim=AD, algorithms=["per", "cmcl", "maddpg"],
                     alpha=[0.6, 1.0, 1.0])
    rb.add(*chunk(10, 0, np.random.default_rng(0)))
    before = rb.state_dict()
    with pytest.raises(ValueError) as err:
        rb.load_state_dict(old["replay"])
    assert str(err.value) == (f"replay snapshot format 1 (this version reads 2): written by an older version; "
                              f"commit {LAST_READER} is the last that reads it")
    without_rng = {k: v for k, v in before.items() if k != "control_rng"}
    with pytest.raises(ValueError, match=f"^replay snapshot without 'control_rng': .* commit {LAST_READER} "):
        rb.load_state_dict(without_rng)
    storage = {k: v for k, v in before["storage"].items() if k != "stale_dropped_total"}
    with pytest.raises(ValueError, match="^replay snapshot without storage.stale_dropped_total: "):
        rb.load_state_dict({**before, "storage": storage})
    with pytest.raises(ValueError, match="format 3"):
        rb.load_state_dict({**before, "format": 3})
    assert rb.state_dict()["storage"]["next_id"] == before["storage"]["next_id"] == 10

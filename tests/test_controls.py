"""The sampling controls and defaults: the permuted control (same probabilities, no information), the
anti-curriculum (ĉ -> 1 − ĉ), the per-algorithm α_s (A8) and rank difficulty (A1), and the reward-row diagnostics."""

import numpy as np
import pytest

from cmcl.config import ConfigError, load_config, preset
from cmcl.io import codec
from cmcl.replay.buffer import ReplayBuffer
from cmcl.replay.diagnostics import buffer_diagnostics, ess_fraction, replay_sampling_diagnostics, sampling_diagnostics
from cmcl.replay.priority import EPS_P, permute_priorities
from cmcl.system import agent_layout, build_replay, make_batched_env
from tests.buffers import make_buffer

N, OD, AD, CAP = 2, 3, 2, 400


def scored_buffer(transform: str = "none", seed: int = 5) -> ReplayBuffer:
    """A full buffer of N = 2 ACL agents whose difficulty column is distinct random values (same for every
    transform; the control's generator is seeded with `seed`)."""
    rb = make_buffer(capacity=CAP, n_agents=N, obs_dim=OD, act_dim=AD, algorithms="acl",
                      difficulty_transform=transform, control_seed=seed)
    rng = np.random.default_rng(0)
    for e in range(CAP // 20):
        t = 20
        rb.add(rng.normal(size=(t, N, OD)), rng.uniform(-1, 1, (t, N, AD)), rng.normal(size=(t, N)),
               rng.normal(size=(t, N, OD)), np.zeros(t), np.full(t, e))
    s = rb.valid_slots()
    rb.update_scores("difficulty", s, rb.generations(s), rng.lognormal(0.0, 1.0, (s.size, N)))
    return rb


@pytest.mark.parametrize("lam", [0.1, 0.3, 0.7])
def test_permuted_control_has_the_same_probabilities_and_ess_but_not_the_same_rows(lam):
    plain, permuted = scored_buffer("none"), scored_buffer("permuted")
    plain.recompute_priorities(lam)
    permuted.recompute_priorities(lam)
    p0, p1 = plain.sampling_distribution(), permuted.sampling_distribution()
    np.testing.assert_allclose(np.sort(p1, axis=0), np.sort(p0, axis=0), rtol=1e-12, atol=0)  # same multiset
    np.testing.assert_allclose(ess_fraction(p1), ess_fraction(p0), rtol=1e-12)
    assert ess_fraction(p0).max() < 0.99  # the comparison is not between two uniform distributions
    # ... but the rows that get the high priorities are not the curriculum's: correlation with KP is ~ 0
    for a in range(N):
        assert np.corrcoef(p0[:, a], p1[:, a])[0, 1] < 0.3
    # a new permutation at every recompute
    before = permuted.sampling_distribution()
    permuted.recompute_priorities(lam)
    assert not np.array_equal(before, permuted.sampling_distribution())


def test_permute_priorities_is_a_column_wise_permutation():
    p = np.arange(12.0).reshape(6, 2)
    out = permute_priorities(p, np.random.default_rng(1))
    assert np.array_equal(np.sort(out, axis=0), p) and not np.array_equal(out, p)


def test_reversed_control_flips_the_order_of_kp_on_the_rising_branch():
    lam = 0.3
    plain, anti = scored_buffer("none"), scored_buffer("reversed")
    d0, d1 = plain.recompute_priorities(lam, details=True), anti.recompute_priorities(lam, details=True)
    c = plain.storage.scores["difficulty"][:CAP, 0].astype(np.float64)
    order = np.argsort(c)  # rows from easiest to hardest (teacher error)
    rise0 = d0["c_hat"][order, 0] <= lam  # the method: the easiest 30 % are on the rising branch
    rise1 = d1["c_hat"][order, 0] <= lam  # anti-curriculum: the hardest 30 %
    assert rise0[: int(0.25 * CAP)].all() and not rise0[-int(0.25 * CAP):].any()
    assert rise1[-int(0.25 * CAP):].all() and not rise1[: int(0.25 * CAP)].any()
    kp0, kp1 = d0["kp"][order, 0], d1["kp"][order, 0]
    assert np.all(np.diff(kp0[rise0]) > 0)  # harder row -> higher KP on the rising branch ...
    assert np.all(np.diff(kp1[rise1]) < 0)  # ... and lower once reversed
    # excluded (KP = 0, priority ε_p): the hardest rows for the method, the easiest for the anti-curriculum
    assert d0["priority"][order[-1], 0] == EPS_P and d1["priority"][order[0], 0] == EPS_P


def test_permuted_control_resumes_exactly_through_a_snapshot():
    rb = scored_buffer("permuted", seed=9)
    rb.recompute_priorities(0.2)
    state = codec.decode_snapshot(codec.encode_snapshot(rb.state_dict()))
    again = scored_buffer("permuted", seed=123)  # a different seed: the state must carry the generator
    again.load_state_dict(state)
    rb.recompute_priorities(0.2)
    again.recompute_priorities(0.2)
    np.testing.assert_array_equal(again.sampling_distribution(), rb.sampling_distribution())
    other = scored_buffer("none")
    with pytest.raises(ValueError, match="difficulty_transform"):
        other.load_state_dict(state)


def test_defaults_rank_difficulty_and_alpha_per_algorithm():
    cfg = load_config()
    priority = cfg.teams["agent"].priority
    assert priority.difficulty_norm == "rank" and priority.difficulty_transform == "none"
    assert priority.alpha is None
    for algorithm, alpha in (("maddpg", 1.0), ("per", 0.6), ("acl", 1.0), ("cmcl", 1.0)):
        assert preset(algorithm).teams["agent"].effective_alpha() == alpha
    tag = preset("cmcl", "tag", opponent="per")  # each team its own α
    layout = agent_layout(tag, make_batched_env(tag, num_envs=1))
    replay = build_replay(tag, layout)
    assert replay.alpha == [1.0, 1.0, 0.6, 0.6] and layout.algorithms == ("cmcl", "cmcl", "per", "per")


def test_explicit_alpha_wins_and_bad_values_are_refused():
    cfg = load_config(None, ["teams.agent.priority.alpha=0.8"])
    assert cfg.teams["agent"].effective_alpha() == 0.8
    cfg = load_config(None, ["teams.agent.algorithm=per", "teams.agent.priority.alpha=1.0"])
    layout = agent_layout(cfg, make_batched_env(cfg, num_envs=1))
    assert set(layout.alpha) == {1.0}
    with pytest.raises(ConfigError, match=r"teams\.agent\.priority\.alpha.*-1\.0"):
        load_config(None, ["teams.agent.priority.alpha=-1"])
    with pytest.raises(ConfigError, match=r"teams\.agent\.priority\.alpha.*inf"):
        load_config(None, ["teams.agent.priority.alpha=inf"])
    with pytest.raises(ConfigError, match=r"teams\.agent\.priority\.difficulty_transform.*'shuffled'"):
        load_config(None, ["teams.agent.priority.difficulty_transform=shuffled"])


def test_each_team_has_its_own_controls():
    """Predators with the permuted control, prey (PER) without: only the predators' columns are shuffled, and a
    buffer with a mix of controls resumes through a snapshot (one transform per agent in its state)."""
    tag = load_config(None, ["env.task=tag", "teams.predator.algorithm=acl", "teams.prey.algorithm=per",
                             "teams.predator.priority.difficulty_transform=permuted",
                             "teams.prey.priority.difficulty_norm=max"])
    layout = agent_layout(tag, make_batched_env(tag, num_envs=1))
    replay = build_replay(tag, layout)
    predators, prey = layout.teams["predator"], layout.teams["prey"]
    assert [replay.difficulty_transform[a] for a in predators] == ["permuted"] * len(predators)
    assert [replay.difficulty_transform[a] for a in prey] == ["none"] * len(prey)
    assert all(replay.sampling[a].permuted for a in predators) and not any(replay.sampling[a].permuted for a in prey)
    assert [replay.sampling[a].difficulty_norm for a in predators] == ["rank"] * len(predators)


def test_a_mixed_control_shuffles_only_the_permuted_agents_columns():
    rb = make_buffer(capacity=CAP, n_agents=N, obs_dim=OD, act_dim=AD, algorithms="acl",
                      difficulty_transform=["permuted", "none"], control_seed=5)
    plain = scored_buffer("none")
    rb.storage = plain.storage  # the same rows and scores
    rb.recompute_priorities(0.3)
    plain.recompute_priorities(0.3)
    p0, p1 = plain.sampling_distribution(), rb.sampling_distribution()
    np.testing.assert_array_equal(p1[:, 1], p0[:, 1])  # agent 1: the method
    assert not np.array_equal(p1[:, 0], p0[:, 0])  # agent 0: shuffled ...
    np.testing.assert_allclose(np.sort(p1[:, 0]), np.sort(p0[:, 0]), rtol=1e-12, atol=0)  # ... the same multiset
    state = codec.decode_snapshot(codec.encode_snapshot(rb.state_dict()))
    assert state["difficulty_transform"] == ["permuted", "none"]
    with pytest.raises(ValueError, match="difficulty_transform"):
        plain.load_state_dict(state)


def test_sampling_diagnostics_count_reward_bearing_rows():
    rewards = np.array([[4.0, -1.0], [0.0, 4.0], [-1.0, 0.0], [0.0, 0.0]])  # agent 0: row 0; agent 1: row 1
    probs = np.array([[0.7, 0.25], [0.1, 0.25], [0.1, 0.25], [0.1, 0.25]])
    d = sampling_diagnostics(probs, rewards)
    assert d["reward_rows_buffer"] == [0.25, 0.25]  # C1 = −1 is not reward-bearing
    assert d["reward_rows_sampled"] == [0.7, 0.25]
    assert d["ess_fraction"][1] == 1.0 and d["ess_fraction"][0] < 0.5


def test_replay_sampling_diagnostics_cover_per_and_uniform_agents():
    rb = make_buffer(capacity=50, n_agents=2, obs_dim=1, act_dim=1, algorithms=["per", "maddpg"], alpha=[0.6, 1.0])
    assert replay_sampling_diagnostics(rb) == {}
    rew = np.zeros((10, 2))
    rew[0] = 4.0
    rb.add(np.zeros((10, 2, 1)), np.zeros((10, 2, 1)), rew, np.zeros((10, 2, 1)), np.zeros(10), np.zeros(10, int))
    rb.update_priorities(0, [0], [50.0])  # PER favours the reward-bearing row
    d = replay_sampling_diagnostics(rb)
    assert d["modes"] == ["per", "uniform"]
    assert d["reward_rows_buffer"] == [0.1, 0.1]
    assert d["reward_rows_sampled"][0] > 0.5 and d["reward_rows_sampled"][1] == pytest.approx(0.1)
    assert d["ess_fraction"][0] < 0.6 and d["ess_fraction"][1] == 1.0


def test_diagnostics_never_change_the_run_nor_draw_a_permutation():
    rb = scored_buffer("permuted")
    rb.recompute_priorities(0.2)
    probs, rng_state = rb.sampling_distribution(), rb.control_rng.bit_generator.state
    d = buffer_diagnostics(rb, 0.3, updates=10)
    assert rb.control_rng.bit_generator.state == rng_state and rb.lam == 0.2
    np.testing.assert_array_equal(rb.sampling_distribution(), probs)
    assert d["sampling"]["ess_fraction"] == [round(float(e), 4) for e in ess_fraction(probs)]
    assert d["curriculum"]["ess_fraction"] == d["sampling"]["ess_fraction"]

"""Replay sampling: each agent's sampling distribution (uniform, PER, the curriculum's), its priorities, IS weights
and argument checks (ALGORITHM.md §3.6, §7 properties 8, 16, 18–20, 22). The stored rows:
tests/test_replay_storage.py."""

import numpy as np
import pytest
from scipy import stats

from cmcl.config import ConfigError, load_config
from cmcl.replay.buffer import ReplayNotReady
from cmcl.replay.curriculum import CurriculumSchedule
from cmcl.replay.priority import EPS_P
from cmcl.replay.sampler import BACKENDS
from tests.buffers import make_buffer
from tests.test_replay_storage import AD, OD, N, chunk, filled, scored_buffer

pytestmark = pytest.mark.filterwarnings("error")


def test_uniform_mode_chi_square_and_not_ready():  # property 16
    rb = make_buffer(capacity=100, n_agents=N, obs_dim=OD, act_dim=AD, min_size=40)
    rng = np.random.default_rng(0)
    rb.add(*chunk(39, 0, rng))
    with pytest.raises(ReplayNotReady, match="needs at least 40"):
        rb.sample(0, 8, rng, beta=0.0)
    rb.add(*chunk(11, 1, rng))
    slots, w = rb.sample(1, 100_000, np.random.default_rng(1), beta=0.4)
    assert np.all(w == 1) and slots.max() < 50
    assert stats.chisquare(np.bincount(slots, minlength=50)).pvalue > 1e-3


@pytest.mark.parametrize("backend", BACKENDS)
def test_eta_zero_cmcl_equals_acl_and_ci_range(backend):  # property 8
    rb = scored_buffer(backend, algorithms=("acl", "cmcl", "cmcl"), eta=[0.5, 0.0, 0.7])
    rb.update_scores("difficulty", rb.valid_slots(), rb.generations(rb.valid_slots()),
                     np.repeat(rb.storage.scores["difficulty"][:300, :1], N, axis=1))
    d = rb.recompute_priorities(0.3, details=True)
    s = rb.valid_slots()
    assert np.array_equal(rb.probabilities(0, s), rb.probabilities(1, s))
    ci = d["priority"] - EPS_P
    assert ci.min() >= -1e-12 and ci[:, 2].max() <= 1.7 and ci[:, 2].max() > 1.0


@pytest.mark.parametrize("alpha", [1.0, 0.6])
def test_unscored_rows_are_drawn_as_often_as_an_average_scored_row(alpha):
    """A11 / DESIGN's provisional priority: rows the teachers have not scored yet (the service's newest rows) are
    neither excluded (the old ε_p floor, which hid them from the learner until scored) nor favoured."""
    rb = scored_buffer(alpha=alpha)
    rb.recompute_priorities(0.2)
    new = rb.add(*chunk(30, 10, np.random.default_rng(2)))  # overwrites slots 0..29, unscored
    scored = np.arange(30, 300)
    for when in ("at insertion", "after a recompute"):
        for agent in (0, 1):  # acl, cmcl
            p_new = rb.probabilities(agent, new)
            assert np.allclose(p_new, p_new[0]), when
            assert p_new.sum() == pytest.approx(30 / 300), when  # their share of the rows: the mean weight each
            raw = rb.sampling[agent].priorities[scored] ** alpha  # the scored rows keep their relative weights
            assert np.allclose(rb.probabilities(agent, scored) / rb.probabilities(agent, scored).sum(), raw / raw.sum())
        assert np.allclose(rb.probabilities(2, new), 1 / 300), when  # maddpg: uniform
        d = rb.recompute_priorities(0.2, details=True)
    assert not d["scored"][new].any() and np.all(d["scored"][30:])
    assert (d["kp"][scored, 0] == 0).any(), "λ = 0.2 excludes some scored rows, so ε_p is not the mean"


def test_a_buffer_without_scores_samples_uniformly():
    rb = filled(algorithms=["acl", "cmcl", "per"])
    rb.recompute_priorities(0.2)
    s = rb.valid_slots()
    for agent in (0, 1):
        assert np.allclose(rb.probabilities(agent, s), 1 / s.size)


@pytest.mark.parametrize("backend", BACKENDS)
def test_priority_recompute_follows_lambda(backend):  # property 22
    rb = scored_buffer(backend, algorithms=("acl", "acl", "maddpg"))
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
    uniform = filled(capacity=50, episodes=1)  # a sampler that takes no feedback: nothing changes, nothing stored
    assert uniform.feedback(0, [0], uniform.generations([0]), {"td_abs": [1.0]}) == (1, False)
    assert not uniform.storage.scored["td_abs"].any()


def test_is_weights_in_buffer():  # property 18
    rb = filled(capacity=200, episodes=5, algorithms=["per", "per", "maddpg"])
    rng = np.random.default_rng(0)
    rb.update_priorities(0, rb.valid_slots(), rng.exponential(1.0, 150))
    _, w = rb.sample(0, 128, rng, beta=0.4)
    assert w.max() == 1.0 and np.all(w <= 1) and w.min() < 1
    _, w1 = rb.sample(1, 128, rng, beta=0.4)  # all priorities equal -> weights all 1
    assert np.all(w1 == 1)
    _, w0 = rb.sample(0, 128, rng, beta=0.0)
    assert np.all(w0 == 1)


def test_per_agent_samplers_independent():  # property 20
    rb = scored_buffer(algorithms=("cmcl", "cmcl", "maddpg"))
    rb.recompute_priorities(0.1)
    s, w = rb.sample_all(128, [np.random.default_rng(i) for i in range(N)], beta=0.0)
    assert s.shape == (N, 128) and w.shape == (N, 128)
    assert not np.array_equal(np.sort(s[0]), np.sort(s[1]))
    prey = rb.sample(2, 60_000, np.random.default_rng(9), beta=0.0)[0]  # predators use CMCL, prey uniform
    assert stats.chisquare(np.bincount(prey, minlength=300)).pvalue > 1e-3
    pred = rb.sample(0, 60_000, np.random.default_rng(9), beta=0.0)[0]
    assert stats.chisquare(np.bincount(pred, minlength=300)).pvalue < 1e-6
    a = rb.sample(0, 50, np.random.default_rng(4), beta=0.0)[0]
    rb.sample(1, 50, np.random.default_rng(5), beta=0.0)
    assert np.array_equal(a, rb.sample(0, 50, np.random.default_rng(4), beta=0.0)[0])


def test_sampling_chosen_once_per_algorithm():
    rb = filled(capacity=300, episodes=10, algorithms=["per", "acl", "maddpg"])
    assert [s.name for s in rb.sampling] == ["per", "acl", "uniform"] and [a for a, _ in rb.curriculum] == [1]
    assert np.all(rb.sampling[0].priorities[:300] == 1.0) and np.all(rb.sampling[1].priorities[:300] == EPS_P)
    with pytest.raises(ValueError, match="algorithm"):
        filled(capacity=300, episodes=1, algorithms=["per", "sorted", "acl"])
    with pytest.raises(ValueError, match="algorithm"):
        filled(capacity=300, episodes=1, algorithms="uniform")  # the sampling's name, not an algorithm


def test_slots_beyond_the_held_rows_and_an_unknown_backend_are_refused():
    """The buffer refuses slots it does not hold; a sampler structure that does not exist is refused at config
    load, naming its key (the buffer receives samplers built from a validated config and checks none again)."""
    rb = filled(capacity=50, episodes=1)
    with pytest.raises(ValueError, match="slots"):
        rb.get([30])
    with pytest.raises(ConfigError, match=r"replay\.backend.*'tree'"):
        load_config(None, ["replay.backend=tree"])

"""Proportional samplers, both backends (ALGORITHM.md §3.6, §7 properties 15, 17, 18)."""

import numpy as np
import pytest
from scipy import stats

from cmcl.replay.sampler import BACKENDS, PrioritySampler, _SumTreeBackend, importance_weights

pytestmark = pytest.mark.filterwarnings("error")


def _fifty_priorities(seed=0):
    p = np.random.default_rng(seed).uniform(0.01, 2.0, 50)
    p[17] = 0.0
    return p


def _chi2_pvalue(slots, p, alpha):
    """Chi-square of drawn slot counts against p^α/Σp^α over the items with p > 0."""
    counts = np.bincount(slots, minlength=p.size)
    w = np.where(p > 0, p**alpha, 0.0)
    expected = w / w.sum() * slots.size
    pos = p > 0
    assert counts[~pos].sum() == 0
    return stats.chisquare(counts[pos], expected[pos]).pvalue


@pytest.mark.parametrize("backend", BACKENDS)
def test_chi_square_matches_p_alpha(backend):  # property 15
    p = _fifty_priorities()
    s = PrioritySampler(50, alpha=0.6, backend=backend)
    s.set_all(p)
    slots = s.sample(100_000, np.random.default_rng(123))
    assert slots.dtype == np.int64
    assert not np.any(slots == 17)
    assert _chi2_pvalue(slots, p, 0.6) > 1e-3


@pytest.mark.parametrize("backend", BACKENDS)
def test_chi_square_pvalues_spread_over_seeds(backend):  # property 15, calibration
    p = _fifty_priorities(1)
    s = PrioritySampler(64, alpha=0.6, backend=backend)
    s.set_all(p)  # slots 50..63 stay empty
    pvals = [_chi2_pvalue(s.sample(20_000, np.random.default_rng(seed)), np.pad(p, (0, 14)), 0.6)
             for seed in range(20)]
    assert stats.kstest(pvals, "uniform").pvalue > 1e-3


@pytest.mark.parametrize("backend", BACKENDS)
def test_alpha_zero_is_uniform_over_positive(backend):  # property 17
    p = _fifty_priorities(2)
    s = PrioritySampler(50, alpha=0.0, backend=backend)
    s.set_all(p)
    slots = s.sample(50_000, np.random.default_rng(7))
    assert _chi2_pvalue(slots, p, 0.0) > 1e-3
    probs = s.probabilities(np.arange(50))
    assert np.allclose(probs[p > 0], 1 / 49) and probs[17] == 0


@pytest.mark.parametrize("backend", BACKENDS)
def test_higher_priority_never_lower_probability(backend):  # property 17
    p = np.random.default_rng(3).random(300)
    s = PrioritySampler(300, alpha=0.6, backend=backend)
    s.set_all(p)
    order = np.argsort(p)
    assert np.all(np.diff(s.probabilities(order)) >= 0)


@pytest.mark.parametrize("capacity", [1, 2, 3, 7, 64, 1000])
def test_backends_agree_and_partial_updates_equal_rebuild(capacity):
    rng = np.random.default_rng(capacity)
    cdf, tree = PrioritySampler(capacity, 0.6, "cdf"), PrioritySampler(capacity, 0.6, "sumtree")
    fresh = PrioritySampler(capacity, 0.6, "sumtree")
    m = max(1, capacity - 1)
    base = rng.random(m)
    for s in (cdf, tree):
        s.set_all(base)
    for _ in range(5):
        slots = rng.integers(0, m, size=max(1, capacity // 10))
        vals = rng.random(slots.size) * 3
        for s in (cdf, tree):
            s.update(slots, vals)
    fresh.set_all(tree.p[:m])
    all_slots = np.arange(capacity)
    assert np.allclose(cdf.probabilities(all_slots), tree.probabilities(all_slots))
    assert np.allclose(tree._impl.tree, fresh._impl.tree)
    assert tree.total == pytest.approx(cdf.total)
    same = tree.sample(1000, np.random.default_rng(0)), cdf.sample(1000, np.random.default_rng(0))
    assert np.array_equal(*same)  # identical inverse-CDF mapping


def test_sum_tree_internal_nodes_are_child_sums():
    t = _SumTreeBackend(13)
    rng = np.random.default_rng(5)
    t.build(rng.random(13))
    t.update(np.array([0, 5, 12, 5]), np.array([9.0, 0.0, 2.5, 1.0]))
    nodes = np.arange(1, t.P)
    assert np.allclose(t.tree[nodes], t.tree[2 * nodes] + t.tree[2 * nodes + 1])
    assert t.tree[t.P + 5] == 1.0 and np.all(t.tree[t.P + 13:] == 0)


@pytest.mark.parametrize("backend", BACKENDS)
def test_empty_and_zero_slots_never_drawn(backend):
    s = PrioritySampler(100, 0.6, backend)
    s.set_all(np.r_[np.zeros(10), np.ones(20)])  # slots 0..9 zero, 30..99 empty
    slots = s.sample(20_000, np.random.default_rng(0))
    assert slots.min() >= 10 and slots.max() < 30
    s.update([3], [1.0])  # a zero slot that gets a priority becomes reachable
    assert np.any(s.sample(2000, np.random.default_rng(1)) == 3)
    s.set_all(np.zeros(5))
    with pytest.raises(ValueError, match="all priorities are 0"):
        s.sample(4, np.random.default_rng(0))


def test_importance_weights():  # property 18
    rng = np.random.default_rng(9)
    probs = rng.dirichlet(np.ones(500))[:128]
    w = importance_weights(probs, 500, 0.4)
    assert w.dtype == np.float32 and w.max() == 1.0 and np.all(w <= 1) and np.all(w > 0)
    assert np.argmax(w) == np.argmin(probs)
    ref = (500 * probs) ** -0.4
    assert np.allclose(w, ref / ref.max(), rtol=1e-6)
    assert np.all(importance_weights(probs, 500, 0.0) == 1)
    assert np.all(importance_weights(np.full(64, 1 / 500), 500, 1.0) == 1)
    assert np.all(np.isfinite(importance_weights(np.array([1e-300, 0.5]), 10**6, 1.0)))


@pytest.mark.parametrize("backend", BACKENDS)
def test_state_dict_round_trip(backend):
    s = PrioritySampler(40, 0.6, backend)
    s.set_all(np.random.default_rng(0).random(30))
    s.update([1, 2], [5.0, 0.0])
    t = PrioritySampler(40, 0.6, "sumtree" if backend == "cdf" else "cdf")
    t.load_state_dict(s.state_dict())
    assert np.allclose(t.probabilities(np.arange(40)), s.probabilities(np.arange(40)))
    with pytest.raises(ValueError, match="alpha"):
        PrioritySampler(40, 0.5, backend).load_state_dict(s.state_dict())
    with pytest.raises(ValueError, match="shape"):
        PrioritySampler(41, 0.6, backend).load_state_dict(s.state_dict())


def test_bad_inputs():
    with pytest.raises(ValueError, match="backend"):
        PrioritySampler(10, 0.6, "heap")
    with pytest.raises(ValueError, match="alpha"):
        PrioritySampler(10, -1.0)
    s = PrioritySampler(10)
    with pytest.raises(ValueError, match="finite"):
        s.set_all([1.0, np.nan])
    with pytest.raises(ValueError, match="finite"):
        s.update([1], [-2.0])
    with pytest.raises(ValueError, match="slots"):
        s.update([10], [1.0])
    with pytest.raises(ValueError, match="capacity"):
        s.set_all(np.ones(11))

"""KP / CP / CI, normalisation and sampling probabilities (ALGORITHM.md §7 properties 1–9, 13, 17)."""

import math
import warnings

import numpy as np
import pytest

from cmcl.replay.priority import (
    EPS_P,
    curiosity_priority,
    curriculum_index,
    kfold_priority,
    normalise_curiosity,
    normalise_difficulty,
    sampling_probabilities,
)

LAMS = [0.05, 0.1, 0.3, 0.5, 0.6, 0.9, 0.999]
pytestmark = pytest.mark.filterwarnings("error")  # any RuntimeWarning fails the test


@pytest.mark.parametrize("lam", LAMS + [1.0])
def test_kp_peak_is_one_at_lambda(lam):  # property 1
    assert kfold_priority(lam, lam) == pytest.approx(1.0, abs=1e-15)


@pytest.mark.parametrize("lam", LAMS)
def test_kp_monotone_branches(lam):  # property 2
    up = kfold_priority(np.linspace(0.0, lam, 2001), lam)
    assert np.all(np.diff(up) > 0)
    hi = min(2 * lam, 1.0)
    c = np.linspace(lam, hi, 2001)[1:]
    if 2 * lam <= 1.0:
        c = c[:-1]  # open interval (λ, 2λ)
    down = kfold_priority(c, lam)
    assert np.all(np.diff(down) < 0)


@pytest.mark.parametrize("lam", [0.05, 0.1, 0.3, 0.45, 0.499])
def test_kp_zero_region_and_origin(lam):  # property 3
    c = np.linspace(2 * lam, 1.0, 101)
    assert np.all(kfold_priority(c, lam) == 0.0)
    assert kfold_priority(0.0, lam) == pytest.approx(math.exp(-lam), rel=1e-15)


@pytest.mark.parametrize("lam", [0.1, 0.3, 0.45])
def test_kp_continuity(lam):  # property 4
    slope = max(1.0, abs(1 / ((1 - lam) * math.log(1 - lam))), abs(1 / math.log(1 - lam)))
    for h in (1e-3, 1e-5, 1e-7, 1e-9):
        assert abs(kfold_priority(lam - h, lam) - 1) <= 2 * slope * h
        assert abs(kfold_priority(lam + h, lam) - 1) <= 2 * slope * h
        assert 0 <= kfold_priority(2 * lam - h, lam) <= 2 * slope * h


def test_kp_range_no_nan_no_warning():  # property 5
    rng = np.random.default_rng(0)
    c = np.concatenate([rng.random(20000), [0.0, 1.0, 0.5]])
    lams = np.concatenate([rng.uniform(1e-6, 1.0, 200), [0.5, 0.75, 0.999999, 1.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for lam in lams:
            kp = kfold_priority(c, float(lam))
            assert np.all(np.isfinite(kp))
            assert kp.min() >= 0.0 and kp.max() <= 1.0
    assert np.allclose(kfold_priority(c, 1.0), np.exp(c - 1.0))


@pytest.mark.parametrize("lam", [0.0, -0.1, 1.0 + 1e-12, 2.0, float("nan")])
def test_kp_rejects_bad_lambda(lam):  # property 6
    with pytest.raises(ValueError, match=r"lam must lie") as info:
        kfold_priority(np.array([0.2]), lam)
    assert repr(lam) in str(info.value)


def test_kp_clamps_c_hat_and_rejects_nan():  # property 6
    assert kfold_priority(-0.5, 0.3) == kfold_priority(0.0, 0.3)
    assert kfold_priority(1.7, 0.7) == kfold_priority(1.0, 0.7)
    with pytest.raises(ValueError, match="c_hat"):
        kfold_priority(np.array([0.1, np.nan]), 0.3)


def test_kp_lam_max_below_one():
    assert kfold_priority(0.5, 0.5, lam_max=0.5) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="lam must lie"):
        kfold_priority(0.5, 0.6, lam_max=0.5)
    with pytest.raises(ValueError, match="lam_max"):
        kfold_priority(0.5, 0.6, lam_max=1.5)


def test_cp_limits():  # property 7
    assert curiosity_priority(0.0) == 0.0
    rho = np.linspace(0.0, 12.0, 5001)[1:]
    cp = curiosity_priority(rho)
    assert np.all(np.diff(cp) > 0) and np.all(cp < 1.0) and np.all(cp > 0)
    assert curiosity_priority(1e3) == pytest.approx(1.0)
    assert curiosity_priority(math.sqrt(10)) == pytest.approx(1 - math.exp(-1), rel=1e-12)
    assert curiosity_priority(math.sqrt(10 * math.log(2))) == pytest.approx(0.5, rel=1e-12)
    assert curiosity_priority(1e300) == 1.0  # no overflow warning
    for bad in (-1.0, np.nan, np.inf):
        with pytest.raises(ValueError, match="rho"):
            curiosity_priority(np.array([1.0, bad]))


def test_ci_range_and_eta_zero_equals_acl():  # property 8
    rng = np.random.default_rng(1)
    c_hat, rho_hat = rng.random(1000), rng.exponential(3.0, 1000)
    for eta in (0.0, 0.1, 0.5, 1.0):
        ci = curriculum_index(kfold_priority(c_hat, 0.3), curiosity_priority(rho_hat), eta)
        assert ci.min() >= 0 and ci.max() <= 1 + eta
    kp = kfold_priority(c_hat, 0.3)
    assert np.array_equal(curriculum_index(kp, curiosity_priority(rho_hat), 0.0), kp), "η = 0 is ACL's KP"
    with pytest.raises(ValueError, match="eta"):
        curriculum_index(0.5, 0.5, -1.0)


def test_normalise_difficulty_max():  # property 9
    rng = np.random.default_rng(2)
    c = rng.exponential(5.0, (400, 3))
    ch = normalise_difficulty(c)
    assert ch.shape == (400, 3) and np.allclose(ch.max(axis=0), 1.0) and ch.min() >= 0
    assert np.allclose(normalise_difficulty(c * 37.5), ch)
    assert np.all(normalise_difficulty(np.zeros((10, 2))) == 0)
    mixed = np.column_stack([np.zeros(10), np.arange(10.0)])  # one all-zero agent column
    out = normalise_difficulty(mixed)
    assert np.all(out[:, 0] == 0) and out[:, 1].max() == 1.0
    assert normalise_difficulty(np.array([0.0, 2.0, 4.0])).tolist() == [0.0, 0.5, 1.0]


def test_sum_and_mean_over_teachers_give_same_c_hat():  # property 13
    rng = np.random.default_rng(3)
    errors = rng.exponential(1.0, (300, 4))  # K−1 = 4 cross-teacher errors per sample
    for method in ("max", "rank"):
        assert np.allclose(normalise_difficulty(errors.sum(1), method), normalise_difficulty(errors.mean(1), method))


def test_normalise_difficulty_rank():
    c = np.array([3.0, 1.0, 1.0, 7.0, 5.0])
    assert normalise_difficulty(c, "rank").tolist() == [0.5, 0.0, 0.0, 1.0, 0.75]
    assert np.all(normalise_difficulty(np.full(6, 2.0), "rank") == 0)
    assert normalise_difficulty(np.array([4.0]), "rank").tolist() == [0.0]
    with pytest.raises(ValueError, match="method"):
        normalise_difficulty(c, "median")
    with pytest.raises(ValueError, match="shape"):
        normalise_difficulty(np.zeros((2, 2, 2)))


def test_normalise_curiosity():
    rng = np.random.default_rng(4)
    rho = rng.exponential(0.01, (500, 2))
    out = normalise_curiosity(rho)
    assert np.allclose(out.std(axis=0), 1.0, rtol=1e-5)
    assert np.allclose(normalise_curiosity(rho * 1000.0), out, rtol=1e-5)
    assert np.all(normalise_curiosity(np.zeros(5)) == 0)
    assert np.array_equal(normalise_curiosity(rho, "raw"), rho)
    with pytest.raises(ValueError, match="rho"):
        normalise_curiosity(np.array([1.0, -1.0]))


def test_sampling_probabilities():  # property 17
    rng = np.random.default_rng(5)
    p = rng.random(200) + EPS_P
    for alpha in (0.3, 0.6, 1.0):
        probs = sampling_probabilities(p, alpha)
        assert probs.sum() == pytest.approx(1.0)
        order = np.argsort(p)
        assert np.all(np.diff(probs[order]) >= 0)
        assert np.allclose(probs, p**alpha / np.sum(p**alpha))
    assert np.allclose(sampling_probabilities(p, 0.0), 1 / 200)
    z = sampling_probabilities(np.array([0.0, 1.0, 3.0]), 0.0)
    assert z.tolist() == [0.0, 0.5, 0.5]
    with pytest.raises(ValueError, match="alpha"):
        sampling_probabilities(p, -0.5)
    with pytest.raises(ValueError, match="positive sum"):
        sampling_probabilities(np.zeros(3), 0.6)

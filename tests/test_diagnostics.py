"""The curriculum diagnostics: branch shares, effective sample size, sampled difficulty and age."""

import numpy as np

from cmcl.replay.diagnostics import buffer_branch_shares, curriculum_diagnostics, ess_fraction
from cmcl.replay.priority import sampling_probabilities


def test_uniform_distribution_has_full_ess_and_buffer_means():
    c_hat = np.linspace(0, 1, 100)[:, None]
    probs = sampling_probabilities(np.ones((100, 1)), 0.6)
    d = curriculum_diagnostics(c_hat, probs, 0.25, age=np.arange(100.0))
    assert d["ess_fraction"] == [1.0]
    assert abs(d["share_rising"][0] + d["share_falling"][0] + d["share_excluded"][0] - 1) < 1e-9
    assert abs(d["share_rising"][0] - 0.25) < 1e-9  # ĉ = i/99 <= 0.25 for i = 0..24: 25 of 100 rows
    assert d["difficulty_sampled"] == d["difficulty_buffer"] and d["age_sampled"] == d["age_buffer"]


def test_concentrated_distribution_is_reported_as_such():
    priority = np.full((100, 2), 1e-6)
    priority[7, 0] = priority[3, 1] = 1.0  # agent 0 samples row 7 (hard, old), agent 1 row 3
    c_hat = np.zeros((100, 2))
    c_hat[7, 0] = 0.9
    d = curriculum_diagnostics(c_hat, sampling_probabilities(priority, 1.0), 0.4, age=np.r_[np.zeros(7), 50.0,
                                                                                         np.zeros(92)])
    assert d["ess_fraction"][0] < 0.011 and d["ess_fraction"][1] < 0.011
    assert d["share_excluded"][0] > 0.99 and d["share_rising"][1] > 0.99
    assert d["difficulty_sampled"][0] > 0.89 and d["age_sampled"][0] > 49


def test_buffer_branch_shares_count_only_scored_entries():
    c_hat = np.array([[0.05, 0.9], [0.15, 0.3], [0.25, 0.0], [0.5, 0.0]])
    scored = np.array([[True, True], [True, True], [True, False], [True, False]])
    shares = buffer_branch_shares(c_hat, scored, lam=0.1)  # scored: 0.05 | 0.15 | 0.25 0.5 0.9 0.3 (>= 0.2)
    assert shares == {"rising": 1 / 6, "falling": 1 / 6, "excluded": 4 / 6}
    assert buffer_branch_shares(c_hat, np.zeros_like(scored), 0.1) == {}
    np.testing.assert_allclose(ess_fraction(np.array([[0.25, 1.0], [0.25, 0], [0.25, 0], [0.25, 0]])), [1.0, 0.25])


def test_ess_fraction_never_exceeds_one_for_uniform_columns_of_any_size():
    """Σ P² of a uniform column rounds below 1/M for many M (M = 21 gave 1.0000000000000087), which the report
    schema refuses as out of [0, 1]: that refusal once dropped a service's final replay report."""
    sizes = np.arange(1, 3001)
    ess = np.array([ess_fraction(np.full((m, 1), 1.0 / m))[0] for m in sizes])
    assert (ess <= 1.0).all(), sizes[ess > 1.0][:5]
    np.testing.assert_allclose(ess, 1.0)

"""The curriculum diagnostics: branch shares, effective sample size, sampled difficulty and age."""

import numpy as np

from cmcl.diagnostics import curriculum_diagnostics
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

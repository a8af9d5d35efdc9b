"""The curriculum grids' sampling figure (lab.report.curriculum_figure): the interpolation of progress rows, the
reward-row ratio and its floors, the per-arm bands, and the figure drawn from summaries of mixed arms."""

import numpy as np
import pytest

from lab.report.curriculum_figure import (
    LEAST_RATIO,
    curriculum_figure,
    episode_lambda_reaches,
    on_grid,
    reward_row_ratio,
    sampling_band,
)


def summary(arm, seed, episodes, lam, ess, sampled, buffer, budget=1_000):
    """A run summary as the grids write it, with only the fields the figure reads."""
    return {"arm": arm, "seed": seed, "budget": budget, "curves": {"coverage": list(np.linspace(0, 1, budget // 100))},
            "sampling_curve": {"episode": episodes, "lambda": lam, "ess": ess, "reward_rows_sampled": sampled,
                               "reward_rows_buffer": buffer, "share_excluded": [0.0] * len(episodes)}}


def test_progress_rows_are_interpolated_onto_the_common_episodes_and_nan_outside_their_span():
    run = summary("cmcl", 0, [200, 400], [0.1, 0.3], [0.2, 0.6], [0.0, 0.1], [0.1, 0.2])
    assert on_grid(run, np.array([100.0, 200.0, 300.0, 400.0, 600.0]), "ess") == pytest.approx(
        [np.nan, 0.2, 0.4, 0.6, np.nan], nan_ok=True)


def test_the_reward_row_ratio_is_sampled_over_buffer_floored_and_undefined_on_an_almost_empty_buffer():
    run = summary("acl", 0, [200, 400, 600], [0.1] * 3, [0.5] * 3, [0.0, 0.05, 0.004], [0.2, 0.1, 0.001])
    ratio = reward_row_ratio(run, np.array([200.0, 400.0, 600.0]))
    assert ratio[0] == LEAST_RATIO  # none sampled: drawn at the log axis's floor, not lost
    assert ratio[1] == pytest.approx(0.5)
    assert np.isnan(ratio[2])  # 0.1% of the buffer: 0 / 0 territory, not drawn


def test_the_band_is_the_mean_of_the_runs_that_have_a_value_at_each_episode():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    x = np.array([1.0, 2.0, 3.0])
    sampling_band(ax, x, [np.array([1.0, np.nan, np.nan]), np.array([3.0, 4.0, np.nan])], "red")
    assert ax.lines[0].get_ydata() == pytest.approx([2.0, 4.0, np.nan], nan_ok=True)
    band = ax.collections[0].get_paths()[0].vertices[:, 1]
    assert np.isfinite(band).all() and band.max() > 2.0 > band.min()  # a band only where two runs have a value
    plt.close(fig)


def test_the_episode_lambda_reaches_half_is_the_mean_over_curriculum_runs_that_got_there():
    runs = [summary("cmcl", 0, [200, 400], [0.4, 0.6], [0.5] * 2, [0.1] * 2, [0.1] * 2),
            summary("acl", 1, [200, 400], [0.3, 0.5], [0.5] * 2, [0.1] * 2, [0.1] * 2),
            summary("cmcl_anti", 2, [200, 400], [0.1, 0.2], [0.5] * 2, [0.1] * 2, [0.1] * 2),  # never got there
            summary("maddpg", 3, [200, 400], [0.9, 1.0], [1.0] * 2, [0.1] * 2, [0.1] * 2)]  # no curriculum
    assert episode_lambda_reaches(runs, 0.5) == pytest.approx((300 + 400) / 2)
    assert episode_lambda_reaches(runs[2:], 0.5) is None


def test_the_figure_draws_every_arm_present_from_runs_with_their_own_progress_episodes(tmp_path):
    import matplotlib.pyplot as plt

    runs = [summary(arm, seed, [208 + seed, 400, 608, 800, 1_000], [0.1, 0.3, 0.5, 0.7, 0.9], [0.3, 0.5, 0.9, 0.9, 0.9],
                    [0.01, 0.02, 0.1, 0.2, 0.2], [0.1, 0.1, 0.1, 0.2, 0.2])
            for arm in ("maddpg", "cmcl", "cmcl_permuted") for seed in (0, 1)]
    runs.append({**runs[0], "sampling_curve": None})  # a run without progress rows is left out, not an error
    png = curriculum_figure(runs, "test task", tmp_path / "figures" / "curriculum_sampling.png")
    assert png.exists() and png.stat().st_size > 20_000
    width, height = plt.imread(png).shape[1::-1]
    assert width > 3 * height  # three panels side by side

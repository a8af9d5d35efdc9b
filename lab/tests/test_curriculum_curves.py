"""The harder task's curve table (lab.report.curriculum_curves): the mean training coverage curve of each arm read at
its crossings and at fixed episodes, as the figure draws it."""

import numpy as np

from lab.report.curriculum_curves import curve_table, first_reaches, mean_curve


def run(arm: str, curve: list[float], budget: int = 1_000) -> dict:
    return {"arm": arm, "budget": budget, "curves": {"coverage": curve}}


def test_the_mean_curve_is_over_the_windows_every_run_has():
    episodes, curve = mean_curve([run("cmcl", [0.1, 0.3, 0.5]), run("cmcl", [0.3, 0.5])])
    assert episodes.tolist() == [100.0, 200.0] and np.allclose(curve, [0.2, 0.4])


def test_a_level_is_reached_between_windows_by_interpolation_at_the_first_window_or_never():
    episodes = np.array([100.0, 200.0, 300.0])
    assert first_reaches(episodes, np.array([0.1, 0.3, 0.6]), 0.2) == 150.0
    assert np.isclose(first_reaches(episodes, np.array([0.1, 0.3, 0.6]), 0.5), 200.0 + 100.0 * 2 / 3)
    assert first_reaches(episodes, np.array([0.25, 0.1, 0.6]), 0.2) == 100.0
    assert first_reaches(episodes, np.array([0.1, 0.15, 0.1]), 0.2) is None


def test_the_table_names_each_arm_in_order_with_its_crossings_and_values_within_the_budget():
    runs = [run("cmcl", [0.0] * 5 + [0.3] * 5), run("maddpg", [0.1] * 2 + [0.6] * 8), run("maddpg", [0.1] * 10)]
    table = curve_table(runs).splitlines()
    assert table[0] == "| arm | seeds | at the first window | first reaches 0.2 | first reaches 0.5 |"  # no episode
    assert table[1] == "| --- | --- | --- | --- | --- |"  # column: 2,500 lies beyond the 1,000-episode budget
    assert table[2].startswith("| MADDPG | 2 | 0.10 | 240 | never |")
    assert table[3].startswith("| CMCL | 1 | 0.00 | 567 | never |")
    assert table[-1].endswith("λ does not reach 0.5 in these runs.")


def test_no_runs_no_table():
    assert curve_table([]) == "no runs yet"


def lambda_run(arm: str, curve: list[float], half_at: float) -> dict:
    """A run of `arm` whose λ grows linearly from 0.1 at episode 0 to 0.5 at `half_at`."""
    return {**run(arm, curve), "sampling_curve": {"lambda": [0.1, 0.5], "episode": [0.0, half_at]}}


def test_arms_whose_lambda_schedules_differ_get_a_column_of_their_own_and_agreeing_ones_a_line():
    flat = [0.1] * 10
    differing = [run("maddpg", flat), lambda_run("cmcl", flat, 400.0), lambda_run("cmcl_stride_x2", flat, 200.0)]
    table = curve_table(differing, ("maddpg", "cmcl_stride_x2", "cmcl")).splitlines()
    assert table[0].startswith("| arm | seeds | λ reaches 0.5 | at the first window |"), table[0]
    assert [line.split(" | ")[2] for line in table[2:5]] == ["—", "200", "400"], table
    assert table[-1].endswith("λ reaches 0.5: each arm's mean episode (the dotted lines).")
    agreeing = [run("maddpg", flat), lambda_run("cmcl", flat, 400.0), lambda_run("cmcl_eta1", flat, 420.0)]
    table = curve_table(agreeing, ("maddpg", "cmcl", "cmcl_eta1")).splitlines()
    assert "λ reaches 0.5" not in table[0] and table[-1].endswith("λ reaches 0.5 at episode 410 on average (the "
                                                                  "dotted line).")

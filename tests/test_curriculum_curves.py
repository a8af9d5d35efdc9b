"""The harder task's curve table (experiments.curriculum_curves): the mean training coverage curve of each arm read at
its crossings and at fixed episodes, as the figure draws it."""

import numpy as np

from experiments.curriculum_curves import curve_table, first_reaches, mean_curve


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

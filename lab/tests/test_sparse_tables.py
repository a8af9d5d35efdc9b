"""The sparse tasks' tables: the calibration's verdict per task, the screen's table and choice, the confirmation's
tests (one-sided Mann-Whitney U, Holm over every comparison) and the goal's verdict.

Every summary here is synthetic (the helpers of tests/test_sparse_confirm.py and synthetic_confirm below): they stand
for finished runs' summaries, never for a component of the code."""

import numpy as np
import pytest
from scipy import stats

from experiments.sparse_arms import SCREEN_ROUNDS, SPARSE_CONFIRM_SEEDS
from lab.report.sparse_tables import (
    calibration_verdicts,
    confirm_table,
    confirm_tests,
    screen_choice_text,
    screen_table,
)
from lab.report.stats import holm
from tests.test_sparse_confirm import every_candidate, synthetic_screen


def synthetic_calibration(task, successes, algorithm="maddpg"):
    return [{"id": f"sparse_calibration_{task}_{algorithm}_s{s}", "grid": "sparse_calibration", "env": task,
             "algorithm": algorithm, "seed": s, "held_out_success": v, "random_success": 0.0, "episodes": 10}
            for s, v in enumerate(successes)]


def test_a_task_stays_while_maddpgs_mean_is_below_the_level_and_says_so_far_until_three_seeds():
    text = calibration_verdicts(synthetic_calibration("vacl_n4", [0.0, 0.1, 0.2])
                                + synthetic_calibration("push_box", [0.3, 0.4, 0.2])
                                + synthetic_calibration("pass", [0.0]) + synthetic_calibration("vacl_n8", [0.9], "per"))
    lines = dict(line[2:].split(": ", 1) for line in text.splitlines())
    assert lines["vacl_n4"].endswith("0.100 over seeds 0, 1, 2: stays in the suite (< 0.2 to stay).")
    assert "0.300 over seeds 0, 1, 2: leaves the suite" in lines["push_box"]
    assert lines["pass"].endswith("(so far: 1 of 3 seeds).") and lines["vacl_n8"] == "not calibrated yet."


def test_the_screen_table_and_choice_read_the_summaries():
    held = every_candidate("vacl_n4", 0.0) | {("vacl_n4", "radius_progress"): (0.9, 0.6, 0.3)} \
        | every_candidate("push_box", 0.0)
    runs = synthetic_screen(held)
    stopped_round = SCREEN_ROUNDS["vacl_n4"][0]
    first = [{**r, "arm": "curriculum_radius", "seed": seed, "held_out_success": 0.0}
             for r, seed in zip(runs[:3], stopped_round.seeds, strict=True)]  # the stopped round's runs stay shown
    for r in runs + first:
        r.update(episodes=1_000, provenance={"commit": "a" * 40, "dirty": False})
    table = screen_table(runs + first)
    radius = next(line for line in table.splitlines() if "| radius_progress |" in line)
    assert "| 200, 201, 202 |" in radius and "| 0.900, 0.600, 0.300 | 0.600 |" in radius
    assert "| 2/8, 2/8, 2/8 |" in radius  # stage 1 of 8 stages
    assert "| vacl_n4 | curriculum_radius | 0, 1, 2 |" in table
    lines = screen_choice_text(runs + first).splitlines()
    assert lines[0] == (f"- vacl_n4, round of seeds 0, 1, 2 ({', '.join(stopped_round.candidates)}): **no choice**: "
                        f"{stopped_round.stopped}.")
    choice = dict(line[2:].split(": ", 1) for line in lines[1:])
    assert choice["vacl_n4"].startswith("**radius_progress** goes to the confirmation")
    assert choice["vacl_n4"].endswith("over seeds 200, 201, 202: radius_progress 0.600; radius_half 0.000; "
                                      "curriculum_half 0.000.")
    assert choice["push_box"].startswith("**no candidate**")
    assert "misses 1 runs" in screen_choice_text(runs[:-1])


def synthetic_confirm(task, means: dict, seed=0):
    """Synthetic confirmation summaries: per arm, held-out success ~ clip(N(means[arm], 0.05)) over the 10 seeds."""
    rng = np.random.default_rng(seed)
    return [{"id": f"sparse_confirm_{task}_{arm}_s{s}", "grid": "sparse_confirm", "env": task, "arm": arm, "seed": s,
             "held_out_success": float(np.clip(m + rng.normal(0, 0.05), 0, 1)), "final_tenth_success": m,
             "provenance": {"commit": "b" * 40, "dirty": False}}
            for s in SPARSE_CONFIRM_SEEDS for arm, m in means.items()]


def test_the_confirmations_tests_are_holm_adjusted_one_sided_u_tests_and_the_goal_needs_all_of_them():
    runs = synthetic_confirm("vacl_n4", {"curriculum_radius": 0.9, "maddpg": 0.0, "control": 0.1}) \
        + synthetic_confirm("push_box", {"intrinsic": 0.85, "maddpg": 0.05, "control": 0.83}, seed=1)
    text = confirm_tests(runs)
    rows = [line for line in text.splitlines() if line.startswith("| vacl_n4") or line.startswith("| push_box")]
    assert [r.split(" | ")[1] for r in rows] == ["curriculum_radius > maddpg", "curriculum_radius > control",
                                                  "intrinsic > maddpg", "intrinsic > control"]
    by = {(r["env"], r["arm"]): [] for r in runs}
    for r in runs:
        by[r["env"], r["arm"]].append(r["held_out_success"])
    ps = [stats.mannwhitneyu(by[t, a], by[t, b], alternative="greater").pvalue
          for t, a in (("vacl_n4", "curriculum_radius"), ("push_box", "intrinsic")) for b in ("maddpg", "control")]
    assert [float(r.split(" | ")[4]) for r in rows] == pytest.approx(holm(ps), abs=1e-4)
    assert "Goal on vacl_n4 (curriculum_radius" in text and "**met**" in text.split("Goal on vacl_n4")[1]
    assert "**not met**" in text.split("Goal on push_box")[1]  # not above its control
    assert "push_box" not in confirm_tests(runs[:-1])  # a task without every run is not tested
    assert "| vacl_n4 | curriculum_radius | 10 |" in confirm_table(runs)

"""The screen's table and selection rule (issue 36): the manipulation check, the ranking, and no selection from an
incomplete screen or from runs of mixed code."""

from experiments.screen_arms import SCREEN_ARMS, SCREEN_SEEDS
from experiments.screen_table import manipulation_ratio, screen_selection, screen_table

AREA = {"maddpg": 0.6, "per": 0.65, "relo": 0.72, "rho": 0.80, "lp": 0.70, "per_floor": 0.66, "cmcl_lam05": 0.5,
        "cmcl_floor": 0.4, "laber": 0.69}


def run(arm, seed, sampled=0.2, buffer=0.1, commit="a" * 40):
    return {"id": f"screen_{arm}_s{seed}", "arm": arm, "seed": seed, "budget": 20_000,
            "auc_coverage": AREA[arm] + 0.001 * seed, "held_out_coverage": 0.9, "held_out_success": 0.5,
            "episodes_to_90": 10_000, "ess_first_quarter": 0.6,
            "sampling_curve": {"episode": [200, 4_800, 5_200, 20_000], "reward_rows_sampled": [sampled, sampled, 9, 9],
                               "reward_rows_buffer": [buffer, buffer, 1, 1]},
            "provenance": {"commit": commit, "dirty": False, "segment_commits": [commit]}}


def test_the_manipulation_ratio_reads_the_first_quarter_only():
    assert manipulation_ratio(run("rho", 100, 0.05, 0.1)) == 0.5  # the later rows (ratio 9) are not read
    assert manipulation_ratio({**run("rho", 100), "sampling_curve": {}}) is None


def test_selection_takes_the_two_best_areas_among_the_rules_that_acted():
    runs = [run(arm, s, sampled=0.01 if arm == "rho" else 0.2) for arm in SCREEN_ARMS for s in SCREEN_SEEDS]
    table = screen_table(runs)
    assert "| reducible held-out loss | candidate | 5 | aaaaaaa |" in table and "did not act" in table
    text = screen_selection(runs)
    # rho has the best area but did not act: ReLo and learning progress are chosen, references never
    assert text.startswith("Selected for the confirmation (code aaaaaaa): ReLo, held-out learning progress.")
    assert "MADDPG" not in text.split("Ranked")[0]


def test_no_selection_from_an_incomplete_screen_or_mixed_code():
    runs = [run(arm, s) for arm in SCREEN_ARMS for s in SCREEN_SEEDS]
    total = len(SCREEN_ARMS) * len(SCREEN_SEEDS)
    assert screen_selection(runs[:-1]).startswith(f"Screen incomplete: {total - 1} of {total} runs")
    runs[0] = run(runs[0]["arm"], runs[0]["seed"], commit="b" * 40)
    assert screen_selection(runs).startswith("Screen runs ran different code (mixed: ")

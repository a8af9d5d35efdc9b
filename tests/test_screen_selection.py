"""The screen's selection rule: the manipulation check, the two rounds (every arm at seed 100, then MADDPG and
round one's three best candidates that acted), the ranking, the gate against MADDPG, and no selection from an
incomplete screen or from runs of mixed code (the screen's table: lab/tests/test_screen_table.py).

Every summary here is synthetic (`run`, `screen_runs`): they stand for finished runs' summaries."""

from experiments.screen_arms import ROUND_ONE_SEEDS, ROUND_TWO_SEEDS, SCREEN_ARMS
from experiments.screen_selection import round_two_arms, selection

AREA = {"maddpg": 0.6, "per": 0.65, "relo": 0.72, "rho": 0.80, "lp": 0.70, "per_floor": 0.66, "cmcl_lam05": 0.5,
        "cmcl_floor": 0.4, "laber": 0.69, "per_actor_uniform": 0.55}
KEPT = ("relo", "lp", "laber")  # round one's three best areas among the candidates that act (rho does not)


def run(arm, seed, sampled=0.2, buffer=0.1, commit="a" * 40, area=None):
    return {"id": f"screen_{arm}_s{seed}", "arm": arm, "seed": seed, "budget": 20_000,
            "auc_coverage": (AREA[arm] if area is None else area[arm]) + 0.001 * (seed - 100),
            "held_out_coverage": 0.9, "held_out_success": 0.5, "episodes_to_90": 10_000, "ess_first_quarter": 0.6,
            "sampling_curve": {"episode": [200, 4_800, 5_200, 20_000], "reward_rows_sampled": [sampled, sampled, 9, 9],
                               "reward_rows_buffer": [buffer, buffer, 1, 1]},
            "provenance": {"commit": commit, "dirty": False, "segment_commits": [commit]}}


def screen_runs(area=AREA, kept=KEPT):
    """The screen's planned runs, round one then round two (MADDPG and `kept`); rho does not act."""
    return [run(arm, s, sampled=0.01 if arm == "rho" else 0.2, area=area)
            for s, arms in ((s, SCREEN_ARMS) for s in ROUND_ONE_SEEDS)
            for arm in arms] + [run(arm, s, area=area) for s in ROUND_TWO_SEEDS for arm in ("maddpg", *kept)]


def test_the_manipulation_ratio_reads_the_first_quarter_only():
    from experiments.screen_selection import manipulation_ratio

    assert manipulation_ratio(run("rho", 100, 0.05, 0.1)) == 0.5  # the later rows (ratio 9) are not read
    assert manipulation_ratio({**run("rho", 100), "sampling_curve": {}}) is None


def test_round_two_takes_maddpg_and_the_three_best_candidates_of_round_one_that_acted():
    runs = screen_runs()
    first = runs[:len(SCREEN_ARMS)]
    assert round_two_arms(first[:-1]) is None  # round one incomplete
    assert round_two_arms(first) == ("maddpg", *KEPT)  # rho's area is the best, but it did not act; per is a reference
    assert selection(first).reason() == ("Screen incomplete: 10 of 18 runs; no selection yet. Round one is in: round "
                                         "two runs ReLo, held-out learning progress, LaBER at seeds 101, 102.")


def test_selection_takes_the_two_best_areas_of_round_two_above_maddpg():
    runs = screen_runs()
    chosen = selection(runs)
    assert chosen.chosen == ("relo", "lp") and chosen.code == "aaaaaaa" and chosen.reference == 0.601
    assert chosen.ranked == ((0.721, 0.5, "relo"), (0.701, 0.5, "lp"), (0.691, 0.5, "laber"))
    # a run at a seed outside the rounds is never read, however good
    extra = run("cmcl_floor", 103, area={"cmcl_floor": 5.0})
    assert selection([*runs, extra]) == chosen


def test_no_candidate_is_selected_unless_its_area_exceeds_maddpgs():
    low = {**AREA, "maddpg": 0.75}
    chosen = selection(screen_runs(area=low))
    assert chosen.chosen == () and chosen.reference == 0.751 and [a for *_, a in chosen.ranked] == list(KEPT)
    assert chosen.reason() == ("No candidate's mean area exceeded MADDPG's 0.751 (code aaaaaaa): none is selected, "
                               "and the confirmation does not run.")
    one = {**AREA, "maddpg": 0.705}  # only ReLo above it
    assert selection(screen_runs(area=one)).chosen == ("relo",)


def test_no_selection_from_an_incomplete_screen_or_mixed_code():
    runs = screen_runs()
    assert selection(runs[:-1]).reason().startswith("Screen incomplete: 17 of 18 runs")
    runs[0] = run(runs[0]["arm"], runs[0]["seed"], commit="b" * 40)
    assert selection(runs).reason().startswith("Screen runs ran different code (mixed: ")

"""The screen's table and the selection as the page says it (lab.report.screen_table): the rows per arm with their
role and manipulation check, the runs at seeds outside the rounds listed and never read, and the selection's text.

Every summary here is synthetic (tests/test_screen_selection.py's helpers): they stand for finished runs'
summaries."""

from experiments.screen_arms import SCREEN_ARMS
from lab.report.screen_table import screen_selection, screen_table
from tests.test_screen_selection import run, screen_runs


def test_after_round_one_the_table_names_the_candidates_dropped_and_the_text_round_two():
    first = screen_runs()[:len(SCREEN_ARMS)]
    assert screen_selection(first) == ("Screen incomplete: 10 of 18 runs; no selection yet. Round one is in: round "
                                       "two runs ReLo, held-out learning progress, LaBER at seeds 101, 102.")
    table = screen_table(first)
    assert "| reducible held-out loss | candidate, round one only | 1 | aaaaaaa |" in table and "did not act" in table


def test_the_selection_text_ranks_the_candidates_and_a_run_outside_the_rounds_is_listed_not_read():
    runs = screen_runs()
    text = screen_selection(runs)
    assert text.startswith("Selected for the confirmation (code aaaaaaa): ReLo, held-out learning progress. Ranked "
                           "by mean area over seeds 100, 101, 102 among round two's candidates that acted (MADDPG "
                           "0.601): ReLo 0.721; held-out learning progress 0.701; LaBER 0.691.")
    extra = run("cmcl_floor", 103, area={"cmcl_floor": 5.0})
    assert screen_selection([*runs, extra]) == text
    assert "not in the table or the selection: CMCL, floor 0.2 seed 103 (area 5.003)" in screen_table([*runs, extra])

"""The confirmation's tables and goal verdicts (lab.report.confirm_tables): the goal per rule, Holm within each
family, no test over runs of mixed code, the report's blocks, the README's sentence on what `make run` trains, and
that `make run` trains what the committed confirmation recommends.

Every summary here is synthetic (tests/test_confirm.py's helpers): they stand for finished runs' summaries."""

import pytest

from experiments.confirm_arms import INTERIM_SEEDS
from experiments.screen_arms import SCREEN_ARMS
from experiments.store import ResultsStore
from lab.report.confirm_tables import GOAL, confirm_decision, confirm_table, confirm_tests, families, recommended
from lab.report.curriculum_tables import curriculum_test_rows, format_tests
from lab.report.report import NO_RUNS, blocks
from lab.report.stats import holm
from tests.test_confirm import AREAS, CHOSEN, fake_screen, synthetic_confirm


def table_rows(text: str, title: str) -> list[list[str]]:
    """The cells of the table after the paragraph starting with `title`."""
    block = text.split(title, 1)[1].split("\n\n")[1]
    return [[c.strip() for c in line.strip("|").split("|")] for line in block.splitlines()[2:]]


def test_a_rule_stopped_at_the_interim_look_is_said_so_in_the_goal(tmp_path):
    store = ResultsStore(tmp_path / "confirm")
    for summary in synthetic_confirm({**AREAS, "relo": 0.60, "lp": 0.64}, seeds=INTERIM_SEEDS):
        store.write(summary)
    goal = {row[0]: row for row in table_rows(confirm_tests(store.load(), CHOSEN), "The goal")}
    assert goal["ReLo"][-1].startswith("goal not met: stopped at the interim look (seeds 0–9)")


def test_the_goal_is_met_only_with_the_gain_the_corrected_interval_and_the_permuted_control():
    runs = synthetic_confirm(AREAS)
    text = confirm_tests(runs, CHOSEN)
    goal = {row[0]: row for row in table_rows(text, "The goal")}
    assert goal["ReLo"][-1] == "**meets the goal**"
    assert goal["held-out learning progress"][-1].startswith("goal not met: the area is +0.0")
    assert f"less than {GOAL:+.2f}" in goal["held-out learning progress"][-1]
    # the same gain over MADDPG, but no better than its own permuted control: not met
    same = synthetic_confirm({**AREAS, "relo_permuted": 0.80})
    row = {r[0]: r for r in table_rows(confirm_tests(same, CHOSEN), "The goal")}["ReLo"]
    assert row[-1].startswith("goal not met: not shown above its permuted control")
    # a large gain with a wide spread: the Holm-corrected interval reaches 0
    wide = synthetic_confirm({**AREAS, "relo_permuted": 0.2})
    for r in wide:  # relo 0.70 and MADDPG 0.59 on average, each ± 0.25 by seed
        if r["arm"] in ("relo", "maddpg"):
            r["auc_coverage"] = (0.70 if r["arm"] == "relo" else 0.59) + (0.25 if r["seed"] % 2 else -0.25)
    row = {r[0]: r for r in table_rows(confirm_tests(wide, CHOSEN), "The goal")}["ReLo"]
    assert row[-1].startswith("goal not met: the Holm-corrected interval [−") and ";" not in row[-1]
    # until every arm has its 20 seeds there is no verdict
    early = confirm_tests(synthetic_confirm(AREAS, seeds=range(19)), CHOSEN)
    assert all(r[-1] == "waits for 20 seeds per arm (or 10 if the interim look stops it)"
               for r in table_rows(early, "The goal"))


def test_holm_is_applied_within_each_family_at_the_familys_alpha():
    runs = synthetic_confirm(AREAS)
    text = confirm_tests(runs, CHOSEN)
    first, second = families(CHOSEN)
    assert first == [("relo", "maddpg", "auc_coverage"), ("lp", "maddpg", "auc_coverage")]
    assert second[:3] == [("relo", "relo_permuted", "auc_coverage"), ("relo", "maddpg", "held_out_success"),
                          ("relo", "maddpg", "episodes_to_90")]
    for comparisons, m in ((first, 2), (second, 6)):
        rows = curriculum_test_rows(runs, comparisons)
        assert len(rows) == m and not any(t.primary for t in rows)
        assert [t.adjusted for t in rows] == pytest.approx(holm([t.p for t in rows]))
        assert {t.level for t in rows} == {0.05 / m}  # the detectable differences at the family's α
        assert format_tests(rows) in text
    assert any(0.05 < t.p < 1 for t in curriculum_test_rows(runs, second))  # not every p is 0 or 1
    assert "Holm-corrected interval (97.5%)" in text  # 1 − 0.05 / 2 for two chosen rules


def test_runs_of_mixed_code_are_not_tested_and_meet_no_goal():
    runs = synthetic_confirm(AREAS)
    for r in runs:
        if r["arm"] == "relo_permuted" and r["seed"] < 10:
            r["provenance"] = {"commit": "d" * 40, "dirty": False, "segment_commits": ["d" * 40]}
    text = confirm_tests(runs, CHOSEN)
    control = {r[0]: r for r in table_rows(text, "Secondary")}["ReLo − ReLo, permuted control"]
    assert control[4] == "not tested: code versions mixed" and control[3].startswith("mixed: ")
    goal = {r[0]: r for r in table_rows(text, "The goal")}
    assert goal["ReLo"][-1].startswith("goal not met: not tested") and "meets" not in goal["ReLo"][-1]
    assert goal["held-out learning progress"][-1].startswith("goal not met: the area")


def test_the_report_blocks_of_the_confirmation(tmp_path):
    fake_screen(tmp_path / "screen")
    empty = blocks(tmp_path)
    assert empty["confirm"] == empty["confirmtests"] == NO_RUNS
    store = ResultsStore(tmp_path / "confirm")
    for summary in synthetic_confirm(AREAS):
        store.write(summary)
    out = blocks(tmp_path)
    assert out["confirm"] == confirm_table(store.load(), CHOSEN)
    roles = {r[0]: r[1:4] for r in table_rows("x\n\n" + out["confirm"], "x")}
    assert roles["ReLo"] == ["rule", "20", "ccccccc"] and roles["ReLo, permuted control"][0] == "permuted control"
    assert roles["MADDPG"][0] == "reference" and len(roles) == 5
    assert "**meets the goal**" in out["confirmtests"]


def test_the_readme_sentence_says_no_verdict_until_complete_then_what_make_run_trains():
    early = confirm_decision(synthetic_confirm(AREAS, seeds=range(12)), CHOSEN)
    assert "no verdict yet" in early and "12 of ReLo; 12 of ReLo, permuted control" in early
    assert early.endswith("`make run` trains uniform replay (MADDPG).")
    assert recommended(synthetic_confirm(AREAS, seeds=range(12)), CHOSEN) is None
    done = confirm_decision(synthetic_confirm(AREAS), CHOSEN)
    assert recommended(synthetic_confirm(AREAS), CHOSEN) == "relo"
    assert "ReLo: area +0.1" in done and "; meets the goal;" in done and "**" not in done
    assert done.endswith("ReLo is the recommended curriculum, and `make run` trains it.")
    assert "(20 seeds per arm, code ccccccc)" in done
    assert confirm_decision(synthetic_confirm(AREAS), CHOSEN, code=False) == done.replace(", code ccccccc", "")
    # neither rule above its permuted control: no recommendation, and the reason is said
    tied = synthetic_confirm({**AREAS, "relo_permuted": 0.80, "lp_permuted": 0.70})
    text = confirm_decision(tied, CHOSEN)
    assert recommended(tied, CHOSEN) is None and "not shown above its permuted control" in text
    assert text.endswith("So no rule is recommended over uniform replay, and `make run` trains uniform replay "
                         "(MADDPG).")


def test_make_run_trains_what_the_committed_confirmation_recommends():
    """The protocol's "Then": `make run` trains the rule that met the goal, else uniform replay."""
    from cmcl.config import load_config
    from experiments.grids import GRIDS, MAKE_RUN
    from experiments.run_spec import ROOT
    from experiments.screen_selection import selection

    chosen = selection(ResultsStore(GRIDS["screen"]).load()).chosen
    best = recommended(ResultsStore(GRIDS["confirm"]).load(), chosen) if chosen else None
    config = ROOT / "configs" / MAKE_RUN["config"]
    follows = SCREEN_ARMS["maddpg" if best is None else best]  # the overrides of what make run must train
    assert load_config(config).to_dict() == load_config(config, follows).to_dict(), \
        f"the confirmation recommends {best or 'uniform replay (maddpg)'}: make run must train it ({follows})"

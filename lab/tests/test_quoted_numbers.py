"""The numbers README.md and docs/LEARNING.md quote from the grids are the report's: regenerating both
pages from the committed summaries, as `python -m lab report --update README.md` and `--update
docs/LEARNING.md` do, changes nothing; a number typed into a block by hand is caught; and the sentences say what the
tests say (withdrawn for mixed code, "not shown" at p >= alpha)."""

import re

import pytest

from experiments.run_spec import ROOT
from lab.report.quoted_curriculum import headline
from lab.report.quoted_words import p_text
from lab.report.report import blocks, update

PAGES = ("README.md", "docs/LEARNING.md")
# marked blocks of these pages that the report does not write, and what does
NOT_FROM_THE_REPORT = {"peer-spread": "bench/peer_table.py (the peer runs of bench scripts, not a grid)"}
BLOCK = re.compile(r"^<!-- (\S+):begin -->\n(.*?)^<!-- \1:end -->$", re.M | re.S)


@pytest.fixture(scope="module")
def report() -> dict[str, str]:
    return blocks()


def regenerated(page: str, text: str, report: dict[str, str], tmp_path) -> str:
    """`page`'s text after `update` with the report's blocks, written to a copy under tmp_path."""
    copy = tmp_path / page.replace("/", "_")
    copy.write_text(text)
    update(copy, report)
    return copy.read_text()


def changed(before: str, after: str) -> list[str]:
    """The names of the blocks whose text differs between two versions of a page."""
    old, new = dict(BLOCK.findall(before)), dict(BLOCK.findall(after))
    return sorted(name for name in old.keys() | new.keys() if old.get(name) != new.get(name))


@pytest.mark.parametrize("page", PAGES)
def test_the_page_is_the_report_of_the_committed_summaries(page, report, tmp_path):
    text = (ROOT / page).read_text()
    again = regenerated(page, text, report, tmp_path)
    assert again == text, (f"stale blocks {changed(text, again)} of {page}: run "
                           f"`python -m lab report --update {page}`")


@pytest.mark.parametrize("page", PAGES)
def test_every_marked_block_of_the_page_is_written_by_the_report(page, report):
    text = (ROOT / page).read_text()
    names = [name for name, _ in BLOCK.findall(text)]
    assert len(names) == len(re.findall(r"^<!-- \S+:begin -->$", text, re.M)), f"{page}: a block without its end"
    assert not set(names) - set(report) - set(NOT_FROM_THE_REPORT), f"{page}: blocks no one regenerates"


def test_a_number_typed_into_a_block_by_hand_is_caught(report, tmp_path):
    text = (ROOT / "README.md").read_text()
    body = dict(BLOCK.findall(text))["headline"]
    number = re.search(r"p = [0-9.]+", body)[0]
    tampered = text.replace(body, body.replace(number, "p = 0.049", 1))
    again = regenerated("README.md", tampered, report, tmp_path)
    assert again != tampered and changed(tampered, again) == ["headline"]
    assert again == text


def runs(auc: dict[str, list[float]], commits: dict[str, list[str]] | None = None) -> list[dict]:
    """Summaries of a navigation curriculum grid: arm -> its runs' areas under coverage (and their commits)."""
    out = []
    for arm, values in auc.items():
        for seed, value in enumerate(values):
            commit = (commits or {}).get(arm, ["a" * 40] * len(values))[seed]
            out.append({"arm": arm, "task": "spread", "seed": seed, "budget": 20_000, "auc_coverage": value,
                        "held_out_success": value, "episodes_to_90": round(20_000 * (1 - value)) + seed,
                        "provenance": {"commit": commit, "dirty": False}})
    return out


def test_a_primary_comparison_of_mixed_code_is_quoted_as_withdrawn_without_a_number():
    grid = runs({"cmcl": [0.3, 0.32, 0.31, 0.29], "maddpg": [0.6, 0.62, 0.61, 0.59]},
                {"cmcl": ["a" * 40, "a" * 40, "b" * 40, "b" * 40], "maddpg": ["a" * 40] * 4})
    text = headline({"curriculum_hard": grid})
    assert "on the harder task the comparison is withdrawn until its grid is re-run at one commit" in text
    assert "p =" not in text and "learns later" not in text


def test_a_primary_comparison_says_not_shown_at_p_above_alpha_and_which_way_below():
    level = runs({"cmcl": [0.60, 0.70, 0.65, 0.55], "maddpg": [0.62, 0.68, 0.60, 0.66]})
    behind = runs({"cmcl": [0.30, 0.32, 0.31, 0.29], "maddpg": [0.60, 0.62, 0.61, 0.59]})
    text = headline({"curriculum": level, "curriculum_tag": behind})
    assert text.startswith("CMCL does not beat uniform replay (MADDPG) in any comparison that stands")
    assert "is not shown to differ at N = 4 (" in text and "learns later on predator-prey (−0.300, p < 0.0001)" in text
    assert "withdrawn" not in text
    ahead = runs({"cmcl": [0.60, 0.62, 0.61, 0.59], "maddpg": [0.30, 0.32, 0.31, 0.29]})
    assert headline({"curriculum": ahead}).startswith("CMCL beats uniform replay (MADDPG) at N = 4")


def test_p_values_are_printed_as_the_pages_print_them():
    assert [p_text(p) for p in (0.0671, 0.00142, 0.000049, 0.4812)] == ["p = 0.067", "p = 0.0014", "p < 0.0001",
                                                                       "p = 0.481"]

"""The numbers README.md and docs/LEARNING.md quote from the grids, as the sentences and tables that hold
them, drawn from the committed summaries by the statistics of lab/RESULTS.md's tables (lab.report.stats, tables,
curriculum_tables). `python -m lab report --update README.md` and `--update docs/LEARNING.md` write them into
their marked blocks; lab/tests/test_quoted_numbers.py regenerates both pages and fails on any difference.

Wording follows the tests, not the author: a comparison whose runs ran different code (experiments.provenance) is
quoted as withdrawn, with no number; one at p ≥ α as "not shown"; a Kaplan-Meier median that is only a lower bound
keeps its "≥" (lab.report.quoted_words, shared by every block).

This module loads the summaries and hands each grid's to the module of its blocks:
* lab.report.quoted_curriculum, the curriculum grids: headline (README.md and docs/LEARNING.md: the primary
  comparison of each curriculum grid), lambdawait (README.md: what `cov` does while λ < 0.5) and learningcurriculum
  (docs/LEARNING.md: times to MA 0.9 of the curriculum grids);
* lab.report.quoted_paper, the paper's grids at the old defaults, in docs/LEARNING.md: learningspread, learningtag
  and learningablations;
* lab.report.quoted_solve, the time-to-solve grids, in docs/LEARNING.md: tts, schedule and ttstag (their tables)
  and refactoring (the service runs after the one-implementation refactoring, lab/results/time_to_solve_issue8).
"""

from __future__ import annotations

from pathlib import Path

from experiments.store import ResultsStore
from lab.report.curriculum_tables import SETTING_TABLES
from lab.report.quoted_curriculum import curriculum_times, headline, lambda_wait
from lab.report.quoted_paper import ablation_summary, spread_summary, tag_summary
from lab.report.quoted_solve import REFACTORING, refactoring_summary, solve_tables
from lab.report.quoted_words import NO_RUNS


def quoted_blocks(where: dict[str, Path], root: Path) -> dict[str, str]:
    """Every quoted block: {marker name: markdown}. where: grid -> its results folder (report.folders);
    root: the results root, which holds REFACTORING."""
    grids = {g: ResultsStore(where[g]).load() for g in ("curriculum", "curriculum_hard", "curriculum_tag",
                                                        "curriculum_stride")}
    paper = ResultsStore(where["spread"]).load()
    spread = [r for r in paper if r.get("grid", "spread") == "spread" and r["task"] == "spread"]
    out = {"headline": headline(grids), "lambdawait": lambda_wait(grids["curriculum"]),
           "learningcurriculum": curriculum_times(grids["curriculum"], grids["curriculum_hard"],
                                                  [r for r in grids["curriculum_hard"]
                                                   if r.get("arm") in SETTING_TABLES["curriculum_stride"][0]]
                                                  + grids["curriculum_stride"])}
    out["learningspread"] = spread_summary(spread) if spread else NO_RUNS
    tag = [r for r in paper if r["task"] == "tag"]
    out["learningtag"] = tag_summary(tag, grids["curriculum_tag"]) if tag else NO_RUNS
    ablations = [r for r in paper if r.get("grid") == "ablations"]
    out["learningablations"] = ablation_summary(
        ablations, [r for r in spread if r["algorithm"] == "cmcl"], [r for r in spread if r["algorithm"] == "acl"]) \
        if ablations else NO_RUNS
    solve = ResultsStore(where["schedule"]).load()
    out.update(solve_tables(solve))
    after = ResultsStore(root / REFACTORING).load()
    out["refactoring"] = refactoring_summary(after, solve) if after else NO_RUNS
    return out

"""The report of every grid's results: the markdown blocks of lab/RESULTS.md and the figures.

Each block is named by its markers in the page, `<!-- name:begin -->` ... `<!-- name:end -->`; `update` replaces
the text between them (a block whose markers the page lacks is only printed):

* spread, seeds, tests: the spread grid (lab/results/reproduce); ablations: the ablations grid against the
  unchanged CMCL runs; tag, tagtests: the tag and winrate grids;
* curriculum, curriculumtests, curriculumstalls: the curriculum grid (lab/results/curriculum); curriculumhard,
  curriculumhardtests, curriculumhardstalls: the curriculum_hard grid (lab/results/curriculum_hard, or its re-run
  at one commit, lab.report.reruns), curriculumhardverdicts its protocol's verdicts (lab.report.curriculum_verdicts),
  curriculumhardcurves its mean coverage curves in numbers (lab.report.curriculum_curves);
  curriculumtag, curriculumtagtests: the curriculum_tag grid (lab/results/curriculum_tag; predator-prey has no
  stall analysis); curriculumstride, curriculumstridetests and curriculumeta, curriculumetatests: the
  curriculum_stride and curriculum_eta grids beside the curriculum_hard grid's MADDPG and CMCL runs, and their
  verdicts, curriculumstrideverdicts and curriculumetaverdicts (lab.report.curriculum_verdicts), and their mean
  coverage curves in numbers, curriculumstridecurves and curriculumetacurves; "no runs yet"
  while a curriculum grid has no summary; the stalls blocks from `python -m lab stalls FOLDER`;
* timetosolve: the schedule and algorithms grids (lab/results/time_to_solve), printed only;
* ownenvs: the own_envs grid (lab/results/own_envs), each environment against the random policy;
* screen, screenselect: the screen of sampling rules (lab/results/screen) and its selection rule;
  confirm, confirmtests: the confirmation of the rules the screen selected (lab/results/confirm), its two Holm
  families and the goal's verdict per rule; "no runs yet" while it has no summary; confirmdecision: README.md's
  sentence on the recommended curriculum and what `make run` trains, from the same summaries;
* sparsecalibration, sparsecalibrationverdicts, sparsescreen, sparsescreenchoice, sparseconfirm,
  sparseconfirmtests: the sparse tasks' calibration, screen and confirmation (lab.report.sparse_tables), the blocks
  of docs/SPARSE_TASKS.md (`python -m lab report --update docs/SPARSE_TASKS.md`);
* reruns: how far the re-runs at one commit are (lab.report.reruns) and which of them the report reads;
* makerun: `make run` measured per seed (lab/results/make_run; earlier measurements in its earlier/<commit>/),
  the block of README.md
  (`python -m lab report --update README.md`);
* the numbers README.md and docs/LEARNING.md quote from the grids (lab.report.quoted): headline, lambdawait (README.md;
  headline in docs/LEARNING.md too), tts, schedule, ttstag, learningcurriculum, learningspread, learningtag,
  learningablations, refactoring (docs/LEARNING.md; `python -m lab report --update docs/LEARNING.md`).

A block name means one text wherever it stands (headline stands in README.md and docs/LEARNING.md), and no two
texts share a name: `update` writes every block whose markers a page has and leaves the rest of the page alone, so any
page can be updated with all of them.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

from experiments.grids import GRIDS, MAKE_RUN, RESULTS, SPARSE_RECALIBRATED
from experiments.labels import ARM_LABEL
from experiments.run_spec import ROOT
from experiments.screen_selection import selection
from experiments.store import ResultsStore
from lab.report.confirm_tables import confirm_decision, confirm_table, confirm_tests
from lab.report.curriculum_curves import curve_table
from lab.report.curriculum_tables import (
    SETTING_TABLES,
    curriculum_table,
    curriculum_tests,
    setting_table,
)
from lab.report.curriculum_verdicts import setting_verdict_table, verdict_table
from lab.report.make_run_table import earlier_runs, make_run_summary, make_run_table
from lab.report.own_env_table import own_env_table
from lab.report.quoted import quoted_blocks
from lab.report.quoted_words import NO_RUNS
from lab.report.reruns import rerun_folders, rerun_text
from lab.report.screen_table import screen_selection, screen_table
from lab.report.sparse_tables import calibration_table, calibration_verdicts, screen_choice_text
from lab.report.sparse_tables import confirm_table as sparse_confirm_table
from lab.report.sparse_tables import confirm_tests as sparse_confirm_tests
from lab.report.sparse_tables import screen_table as sparse_screen_table
from lab.report.stalls import early_learner_table, load_stalls, stall_table
from lab.report.tables import (
    ablation_table,
    seeds_table,
    solve_table,
    spread_table,
    tag_table,
    tag_tests_table,
    tests_table,
)

CURRICULUM_BLOCKS = {"curriculum": ("curriculum", "curriculumtests", "curriculumstalls", "curriculumearly"),
                     "curriculum_hard": ("curriculumhard", "curriculumhardtests", "curriculumhardstalls",
                                         "curriculumhardearly"),
                     "curriculum_tag": ("curriculumtag", "curriculumtagtests", None, None)}  # grid -> its blocks
# the harder task's settings grids (SETTING_TABLES) -> (their table block, tests block, figure title's tail)
SETTING_BLOCKS = {"curriculum_stride": ("curriculumstride", "curriculumstridetests", "CMCL at three λ strides"),
                  "curriculum_eta": ("curriculumeta", "curriculumetatests", "CMCL at η = 0.5 and 1")}


# the sampling figures of the grids re-run at one commit: block -> (grid, alt text); the link follows the folder the
# report reads (the re-run's once complete: lab.report.reruns), from lab/
FIGURE_LINKS = {
    "curriculumhardfigure": ("curriculum_hard", "Harder task: training coverage, ESS and reward rows sampled against "
                                                "the buffer, per arm"),
    "curriculumstridefigure": ("curriculum_stride", "Harder task: CMCL at three λ strides beside MADDPG: training "
                                                    "coverage, ESS and reward rows sampled against the buffer"),
    "curriculumetafigure": ("curriculum_eta", "Harder task: CMCL at η = 0.5 and 1 beside MADDPG: training coverage, "
                                              "ESS and reward rows sampled against the buffer")}


def figure_link(folder: Path, alt: str) -> str:
    """The markdown image of a grid's sampling figure (<folder>/figures/curriculum_sampling.png), linked from
    lab/RESULTS.md."""
    return f"![{alt}]({os.path.relpath(folder / 'figures' / 'curriculum_sampling.png', ROOT / 'lab')})"


def folders(results: Path | None = None) -> dict[str, Path]:
    """grid -> its results folder, under `results` (default: the registry's, lab/results); a grid re-run at one
    commit (lab.report.reruns) -> its re-run's folder once that is complete."""
    where = {name: path if results is None else results / path.name for name, path in GRIDS.items()}
    return {**where, **rerun_folders(results)}


def blocks(results: Path | None = None) -> dict[str, str]:
    """Every block of the report that has something to show: {marker name: markdown}."""
    where = folders(results)
    runs = ResultsStore(where["spread"]).load()
    spread = [r for r in runs if r.get("grid", "spread") == "spread"]
    ablations = [r for r in runs if r.get("grid") == "ablations"]
    tag = [r for r in runs if r["task"] == "tag"]
    out = {"spread": spread_table(spread), "seeds": seeds_table(spread), "tests": tests_table(spread)}
    if ablations:
        out["ablations"] = ablation_table(ablations, [r for r in spread if r["algorithm"] == "cmcl"]
                                          + [r for r in runs if r.get("grid") == "ablation_reference"])
    if tag:
        out["tag"], out["tagtests"] = tag_table(tag), tag_tests_table(tag)
    loaded = {}
    for grid_name, (table, tests, stalls, early) in CURRICULUM_BLOCKS.items():
        curriculum = loaded[grid_name] = ResultsStore(where[grid_name]).load()
        out[table], out[tests] = (curriculum_table(curriculum), curriculum_tests(curriculum)) if curriculum \
            else (NO_RUNS, NO_RUNS)
        if stalls is not None:
            records = load_stalls(where[grid_name])
            out[stalls], out[early] = stall_table(records, ARM_LABEL), early_learner_table(records, ARM_LABEL)
    hard = loaded["curriculum_hard"]
    out["curriculumhardverdicts"], out["curriculumhardcurves"] = verdict_table(hard), curve_table(hard)
    for grid_name, (table, tests, _) in SETTING_BLOCKS.items():
        arms, comparisons = SETTING_TABLES[grid_name]
        runs = setting_runs(where, grid_name, hard)
        out[table], out[tests] = (setting_table(runs, arms), curriculum_tests(runs, comparisons)) \
            if any(r["grid"] == grid_name for r in runs) else (NO_RUNS, NO_RUNS)
        out[f"{table}verdicts"] = setting_verdict_table(runs, grid_name)
        out[f"{table}curves"] = curve_table(runs, arms) if any(r["grid"] == grid_name for r in runs) else NO_RUNS
    solve = ResultsStore(where["schedule"]).load()
    if solve:
        out["timetosolve"] = solve_table(solve)
    own = ResultsStore(where["own_envs"]).load()
    out["ownenvs"] = own_env_table(own) if own else NO_RUNS
    screen = ResultsStore(where["screen"]).load()
    out["screen"] = screen_table(screen) if screen else NO_RUNS
    out["screenselect"] = screen_selection(screen)
    confirm, chosen = ResultsStore(where["confirm"]).load(), selection(screen)
    out["confirm"], out["confirmtests"] = (NO_RUNS, NO_RUNS) if not confirm else \
        (chosen.reason(), chosen.reason()) if not chosen.chosen else \
        (confirm_table(confirm, chosen.chosen), confirm_tests(confirm, chosen.chosen))
    # README.md's sentence (no commits) and the record's
    out["confirmdecision"] = confirm_decision(confirm, chosen.chosen, code=False) if chosen.chosen else chosen.reason()
    out["confirmdecision_record"] = confirm_decision(confirm, chosen.chosen) if chosen.chosen else chosen.reason()
    out["reruns"] = rerun_text(results)
    calibration = ResultsStore(where["sparse_calibration"]).load()
    out["sparsecalibration"] = calibration_table(calibration) if calibration else NO_RUNS
    out["sparsecalibrationverdicts"] = calibration_verdicts(calibration)
    recalibration = ResultsStore(where["sparse_recalibration"]).load()
    out["sparserecalibration"] = calibration_table(recalibration) if recalibration else NO_RUNS
    out["sparserecalibrationverdicts"] = calibration_verdicts(recalibration, SPARSE_RECALIBRATED)
    sparse_screen = ResultsStore(where["sparse_screen"]).load()
    out["sparsescreen"] = sparse_screen_table(sparse_screen) if sparse_screen else NO_RUNS
    out["sparsescreenchoice"] = screen_choice_text(sparse_screen)
    sparse_confirm = ResultsStore(where["sparse_confirm"]).load()
    out["sparseconfirm"] = sparse_confirm_table(sparse_confirm) if sparse_confirm else NO_RUNS
    out["sparseconfirmtests"] = sparse_confirm_tests(sparse_confirm)
    out |= {block: figure_link(where[grid_name], alt) for block, (grid_name, alt) in FIGURE_LINKS.items()}
    make_runs = ResultsStore(where["make_run"]).load()
    out["makerun"] = make_run_summary(make_runs, MAKE_RUN["config"])  # README.md's block
    out["makerun_record"] = make_run_table(make_runs, MAKE_RUN["config"], earlier_runs(where["make_run"]))  # the record
    quoted = quoted_blocks(where, RESULTS if results is None else results)  # README.md's and LEARNING.md's
    assert not quoted.keys() & out.keys(), f"two texts named {sorted(quoted.keys() & out.keys())}"
    return {**out, **quoted}


def setting_runs(where: dict[str, Path], grid_name: str,
                 hard: list[dict[str, Any]] | None = None) -> list[dict[str, Any]]:
    """A harder-task settings grid's runs with the harder task's runs of the other arms of its table (MADDPG and the
    default CMCL) beside them; `hard`: the harder task's runs when already loaded (else read from its folder)."""
    arms = SETTING_TABLES[grid_name][0]
    hard = ResultsStore(where["curriculum_hard"]).load() if hard is None else hard
    hard = [r for r in hard if r.get("arm") in arms]
    return [*hard, *ResultsStore(where[grid_name]).load()]


CURRICULUM_TASKS = {"curriculum": "Sparse navigation N=4",  # grid -> the task named in its figure's title
                    "curriculum_hard": "Harder sparse navigation N=4 (cover radius 0.075)",
                    "curriculum_tag": "Sparse predator-prey, each arm's predators against MADDPG prey"}


def figures(results: Path | None = None) -> list[Path]:
    """Draw the figures of the paper's grids into <reproduce folder>/figures/ and each curriculum grid's sampling
    figure into <its folder>/figures/curriculum_sampling.png; returns the PNGs written."""
    from lab.report.curriculum_figure import curriculum_figure
    from lab.report.figures import figures as draw

    where = folders(results)
    written = draw(ResultsStore(where["spread"]).load(), where["spread"] / "figures")
    for grid_name, task in CURRICULUM_TASKS.items():
        runs = ResultsStore(where[grid_name]).load()
        if runs:
            written.append(curriculum_figure(runs, task, where[grid_name] / "figures" / "curriculum_sampling.png"))
    for grid_name, (_, _, title) in SETTING_BLOCKS.items():
        runs = setting_runs(where, grid_name)
        if any(r["grid"] == grid_name for r in runs):
            written.append(curriculum_figure(runs, f"{CURRICULUM_TASKS['curriculum_hard']}, {title}",
                                             where[grid_name] / "figures" / "curriculum_sampling.png",
                                             SETTING_TABLES[grid_name][0]))
    return written


def update(path: Path, new: dict[str, str]) -> None:
    """Replace each `<!-- name:begin -->...<!-- name:end -->` block of `path` by its new text."""
    text = path.read_text()
    for name, body in new.items():
        text = re.sub(rf"(<!-- {name}:begin -->\n).*?(<!-- {name}:end -->)",
                      lambda m, body=body: m[1] + body + "\n" + m[2], text, flags=re.S)
    path.write_text(text)

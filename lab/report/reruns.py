"""Grids re-run at one commit: the harder task's curriculum grid, whose first runs mixed code versions, and
the λ-stride and η grids whose tests set their arms beside its MADDPG and CMCL runs. Each is re-run from a worktree
at RERUN_COMMIT into a folder of its own (`python -m experiments run NAME --seeds 0 … 9 --out
lab/results/NAME_<commit>`), and the report reads that folder in place of the grid's first one once it holds every
run of RERUN_SEEDS; until then the first folder stays (its mixed cells untested) and `rerun_progress` says how far the
re-run is. Reads only the folders' summaries."""

from __future__ import annotations

from pathlib import Path

from experiments.grids import RESULTS, grid
from experiments.store import ResultsStore

RERUN_COMMIT = "b44bcaa"  # the commit every re-run runs at (a worktree at it; the summaries record the full hash)
RERUN_SEEDS = tuple(range(10))
RERUNS = {name: RESULTS / f"{name}_{RERUN_COMMIT}" for name in ("curriculum_hard", "curriculum_stride",
                                                                  "curriculum_eta")}  # grid -> its re-run's folder


def rerun_progress(name: str, folder: Path) -> tuple[int, int]:
    """(runs of grid `name` at RERUN_SEEDS with a summary in `folder`, runs it needs)."""
    needed = {run.id for run in grid([name], list(RERUN_SEEDS))}
    return len(needed & ResultsStore(folder).finished()), len(needed)


def rerun_status(results: Path | None = None) -> dict[str, tuple[Path, int, int]]:
    """grid -> (its re-run's folder under `results`, default lab/results; runs in; runs needed)."""
    status = {}
    for name, path in RERUNS.items():
        folder = path if results is None else results / path.name
        status[name] = (folder, *rerun_progress(name, folder))
    return status


def rerun_folders(results: Path | None = None) -> dict[str, Path]:
    """grid -> its re-run's folder (under `results`, default lab/results), for every re-run that is complete."""
    return {name: folder for name, (folder, done, needed) in rerun_status(results).items() if done == needed}


LABEL = {"curriculum_hard": "the harder task's curriculum grid", "curriculum_stride": "the λ-stride grid",
         "curriculum_eta": "the η grid"}


def rerun_text(results: Path | None = None) -> str:
    """lab/RESULTS.md's block on the re-runs: how many runs each holds of those it needs, and which folder the report
    reads for each grid."""
    status = rerun_status(results)
    parts = [f"{LABEL[name]} {done} of {needed} runs (`lab/results/{folder.name}`)"
             for name, (folder, done, needed) in status.items()]
    reading = [LABEL[name] for name, (_, done, needed) in status.items() if done == needed]
    return (f"Re-runs at one commit ({RERUN_COMMIT}, seeds {RERUN_SEEDS[0]}–{RERUN_SEEDS[-1]}): " + "; ".join(parts)
            + ". The report reads a re-run in place of the grid's first folder once it holds every run: "
            + (f"now for {', '.join(reading)}." if reading else "none is complete yet, so the tables below are the "
               "first runs', and the tests on their mixed cells are not run."))

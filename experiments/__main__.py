"""Command line of the grid runner: train the runs of one or more grids.

    python -m experiments run GRID [GRID ...] [--seeds 0 1 2 3 4] [--jobs 2] [--out DIR]
            [--arms ...] [--cells ...] [--ablations ...] [--algorithms ...] [--modes inline service] [--episodes 20000]
            [--tasks ...] [--screen DIR] [--ray [--address ADDR]] [--allow-dirty]

`run` is resumable (experiments.runner): rerun the same command after a stop. With --ray (or --address) each run is
a Ray Tune trial of 1 CPU, on an embedded Ray or the cluster at ADDR (experiments.on_ray), the path of `python -m cmcl
tune`. Its results go to the grid's folder of the registry (experiments.grids.GRIDS, under lab/results/) unless --out
names another. Seeds default to 0-4, and to 0-19 for the confirm grid alone, whose arms the screen's summaries
select (--screen: their folder); alone, the sparse screen and sparse_scale default to every seed of their rounds
(0-2, 200-202), sparse_recalibration to 0-2 and sparse_confirm, whose arms the sparse screen's summaries select, to
100-109. Exit code of `run`: 0 when every run finished, 1 when some failed (each is named in the output), 2 when it
refused to start. The tables and figures drawn from the summaries are the research record's (`python -m lab report`,
outside the package).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from cmcl.replay.registry import PAPER_ALGORITHMS
from cmcl.run.provenance import code_state
from experiments.confirm_arms import CONFIRM_SEEDS, has_permuted_control
from experiments.grids import (
    ABLATIONS,
    CURRICULUM_ARMS,
    EPISODES,
    GRIDS,
    SCALE_CELLS,
    SPARSE_TASKS,
    grid,
    prefix_reference_runs,
)
from experiments.labels import PERMUTED
from experiments.on_ray import GridOnRayError, run_grid_on_ray
from experiments.run_spec import ROOT, Run
from experiments.runner import run_grid
from experiments.screen_arms import SCREEN_ARMS, SCREEN_REFERENCES, SCREEN_SEEDS, rule_algorithm
from experiments.sparse_arms import CALIBRATION_SEEDS, SPARSE_CONFIRM_SEEDS, SPARSE_SCREEN_SEEDS
from experiments.store import ResultsStore


def shown(path: Path) -> str:
    return str(path.relative_to(ROOT) if path.is_relative_to(ROOT) else path)


SEEDS = [0, 1, 2, 3, 4]  # a grid's seeds unless --seeds names others (alone, the confirm grid: CONFIRM_SEEDS; the
# screen: SCREEN_SEEDS; the sparse screen and its scale: SPARSE_SCREEN_SEEDS, every round's; the sparse confirmation:
# SPARSE_CONFIRM_SEEDS)
# what --arms may name: the curriculum grids', the screen's and the confirmation's arms (a screen candidate's permuted
# control is one of the latter once the screen selects it)
ARMS = list(dict.fromkeys([*CURRICULUM_ARMS, *SCREEN_ARMS,
                           *(f"{arm}{PERMUTED}" for arm, sets in SCREEN_ARMS.items()
                             if arm not in SCREEN_REFERENCES and has_permuted_control(rule_algorithm(sets)))]))


# what --tasks selects
SPARSE_GRIDS = ("sparse_calibration", "sparse_recalibration", "sparse_screen", "sparse_scale", "sparse_confirm")


def has_arms(run: Run) -> bool:
    """Whether `run` belongs to a grid whose runs --arms selects: a curriculum grid's, the screen's or the
    confirmation's."""
    return run.grid in ("screen", "confirm") or (run.grid != "scale" and run.arm in CURRICULUM_ARMS)


def grid_args(args: argparse.Namespace) -> tuple:
    """`grid`'s arguments from the command line: a lone grid's default seeds, and a lone screen's or confirmation's
    --out as the folder whose summaries decide its later round."""
    own = args.out if len(args.grids) == 1 else None
    seeds = args.seeds or (
        {"confirm": list(CONFIRM_SEEDS), "screen": list(SCREEN_SEEDS), "sparse_screen": list(SPARSE_SCREEN_SEEDS),
         "sparse_scale": list(SPARSE_SCREEN_SEEDS), "sparse_recalibration": list(CALIBRATION_SEEDS),
         "sparse_confirm": list(SPARSE_CONFIRM_SEEDS)}
        .get(args.grids[0], SEEDS)
        if len(args.grids) == 1 else SEEDS)
    screen = own if args.grids == ["screen"] and own else args.screen
    return args.grids, seeds, args.algorithms, args.episodes, screen, own if args.grids == ["confirm"] else None


def waiting_seeds(args: argparse.Namespace, every: list[Run]) -> list[int]:
    """The seeds of a screen or confirmation without a run in `every` (`grid`'s runs before the filters) because they
    wait for an earlier round."""
    names, seeds = grid_args(args)[:2]
    return [s for s in seeds if not any(r.seed == s for r in every)] if set(names) & {"screen", "confirm"} else []


def selected_runs(args: argparse.Namespace, every: list[Run] | None = None) -> list[Run]:
    """The runs of `args.grids` (`every`, when the caller has `grid`'s runs already) that the filters keep (--arms
    filters only the curriculum grids' and the screen's arms, --cells only the scale grid's cells), with the prefix
    references the kept ablations need."""
    runs = [r for r in (grid(*grid_args(args)) if every is None else every)
            if (r.ablation is None or r.ablation in args.ablations)
            and (args.arms is None or r.arm in args.arms or not has_arms(r))
            and (r.arm not in SCALE_CELLS or r.arm in args.cells) and r.mode in args.modes
            and (args.tasks is None or r.env in args.tasks or r.grid not in SPARSE_GRIDS)]
    return runs + prefix_reference_runs(runs, args.episodes)


def refused_numbers(args: argparse.Namespace) -> str | None:
    """The one-line refusal of a number `run` cannot train with (before any run starts; before, --jobs 0 ended in a
    ThreadPoolExecutor traceback and --seeds -1 or --episodes 0 started every run only for each to fail), or None."""
    if args.jobs < 1:
        return f"--jobs must be >= 1 (runs trained at once), got {args.jobs}"
    if args.episodes < 1:
        return f"--episodes must be >= 1, got {args.episodes}"
    negative = [s for s in args.seeds or () if s < 0]
    return f"--seeds must be >= 0 (run.seed), got {negative[0]}" if negative else None


def run(args: argparse.Namespace) -> int:
    refusal = refused_numbers(args)
    if refusal is not None:
        print(f"error: {refusal}", file=sys.stderr)
        return 2
    try:
        every = grid(*grid_args(args))
    except ValueError as refused:  # ConfirmNotReady, SparseNotReady, or a seed outside the screen's rounds
        print(f"error: {refused}", file=sys.stderr)
        return 2
    runs = selected_runs(args, every)
    waiting = waiting_seeds(args, every)
    if waiting:
        print(f"seeds {' '.join(map(str, waiting))} wait for the earlier round (the screen's round one, the "
              f"confirmation's interim look): run this command again once it is in", flush=True)
    folders = {GRIDS[g] for g in args.grids}
    if args.out is None and len(folders) > 1:
        print(f"error: grids {args.grids} keep their results in different folders; run them one at a time or "
              f"name one with --out", file=sys.stderr)
        return 2
    store = ResultsStore(args.out or folders.pop())
    store.root.mkdir(parents=True, exist_ok=True)
    commit, dirty = code_state()
    if dirty and not args.allow_dirty:
        print(f"error: the checkout at {ROOT} has uncommitted changes to tracked files (commit "
              f"{(commit or '?')[:7]}); commit them, or pass --allow-dirty (every summary then records dirty: true)",
              file=sys.stderr)
        return 2
    print(f"grid code: commit {commit or 'unknown'}" + (" with uncommitted changes (--allow-dirty)" if dirty else ""),
          flush=True)
    say = lambda line: print(line, flush=True)  # noqa: E731
    if args.ray or args.address:
        try:
            failed = run_grid_on_ray(runs, store, args.jobs, args.address, report=say)
        except GridOnRayError as refused:
            print(f"error: {refused}", file=sys.stderr)
            return 2
    else:
        failed = run_grid(runs, store, args.jobs, report=say)
    print(f"results: {shown(store.write_csv())}" + (f"; {failed} runs failed (a rerun retries them)" if failed else ""))
    return 1 if failed else 0


def build_parser() -> argparse.ArgumentParser:
    """The command line: run."""
    parser = argparse.ArgumentParser(prog="python -m experiments", description=__doc__.split("\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    p = commands.add_parser("run", help="train the runs of one or more grids (resumable)")
    p.add_argument("grids", nargs="+", choices=list(GRIDS), metavar="GRID", help=f"one of {', '.join(GRIDS)}")
    p.add_argument("--seeds", nargs="+", type=int, default=None,
                   help="default 0 1 2 3 4; alone, the confirm grid 0 to 19, the screen 100 101 102")
    p.add_argument("--jobs", type=int, default=1, help="runs trained at once (one core each)")
    p.add_argument("--out", type=Path, default=None, help="results folder (default: the grid's, lab/results/...)")
    p.add_argument("--arms", nargs="+", choices=ARMS, default=None,
                   help="curriculum grids, the screen and the confirmation: only these arms (default: all)")
    p.add_argument("--cells", nargs="+", choices=list(SCALE_CELLS), default=list(SCALE_CELLS),
                   help="scale grid: only these cells")
    p.add_argument("--ablations", nargs="+", choices=list(ABLATIONS), default=list(ABLATIONS),
                   help="ablations grid: only these variants")
    p.add_argument("--algorithms", nargs="+", choices=PAPER_ALGORITHMS, default=list(PAPER_ALGORITHMS),
                   help="paper grids: only these of the paper's four algorithms")
    p.add_argument("--modes", nargs="+", choices=["inline", "service"], default=["inline", "service"],
                   help="algorithms grid: only these runners")
    p.add_argument("--tasks", nargs="+", choices=list(SPARSE_TASKS), default=None,
                   help="sparse grids (sparse_calibration, _recalibration, _screen, _scale, _confirm): only these "
                        "tasks (default: all)")
    p.add_argument("--episodes", type=int, default=EPISODES, help="budget of every run (the paper: 20,000)")
    p.add_argument("--screen", type=Path, default=None,
                   help="confirm grid: the screen's results folder that selects its arms (default: the screen's)")
    p.add_argument("--ray", action="store_true",
                   help="train the runs as Ray Tune trials of 1 CPU on an embedded Ray (inline runs only)")
    p.add_argument("--address", default=None,
                   help="with --ray implied: the Ray cluster to run the trials on (results on shared storage)")
    p.add_argument("--allow-dirty", action="store_true",
                   help="train even though tracked files differ from the commit (recorded in every summary)")
    p.set_defaults(handler=run)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return args.handler(args)


if __name__ == "__main__":
    sys.exit(main())

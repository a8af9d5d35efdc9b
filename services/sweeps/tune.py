"""`python -m cmcl tune`: a sweep of training runs on Ray Tune, Optuna's search and the ASHA scheduler.

    python -m cmcl tune --config F --search KEY=DISTRIBUTION [--search ...] --trials N --out DIR
                        [--objective seconds_to_coverage|held_out_coverage|held_out_success] [--coverage 0.9]
                        [--max-seconds S] [--runner inline|service] [--seeds K] [--set KEY=VALUE ...]
                        [--address ADDR] [--quiet]
    python -m cmcl tune --resume DIR

Every `--search` key is checked against the config schema first (services/sweeps/space.py); then each trial is one
run in a Tune actor (services/sweeps/trial.py), in DIR/runs/<trial id>/: an inline run of 1 CPU by default, or with
`--runner service` a run of the service (what `make run` trains), its roles Ray actors in the trial's placement group
(so the service's own keys, e.g. service.rollout_workers' CPUs, can be searched too). With `--seeds K` a trial is K
runs of its settings one after the other (run.seed + 0 .. K-1, in DIR/runs/<trial id>/s<k>/), scored by their median
seconds (or mean held-out value): one seed's time varies too much to rank settings by. Optuna (TPE) proposes the
settings of each trial from the objective of those before; ASHA stops a trial early whose training moving average
(coverage, or success) is behind the others' at the same training second (or episode, without a time budget). Ray:
an embedded one sized to this machine (its servers on 127.0.0.1, reaped with this process), the current one when
this process already has one (the tests'), or the cluster at --address. At the end: a table of the trials (params,
objective, episodes, training seconds, how each ended) on stdout and in DIR/results.json, the best trial's settings
as `--set` flags ready to paste, in DIR/best.json, and its whole config in DIR/best_config.toml (`--config` it).
Ctrl-C stops the sweep in order (each running trial drained and checkpointed); `--resume DIR` goes on with Tune's
`Tuner.restore`, each unfinished trial resuming its own run. Exit codes: 0 done, 1 a trial failed, 2 bad
arguments, 130 stopped by Ctrl-C (resumable).
"""

from __future__ import annotations

import argparse
import json
import shutil
import signal
import sys
from pathlib import Path
from typing import Any

from cmcl.config import ConfigError
from cmcl.io.atomic import atomic_write_bytes
from cmcl.io.resume_hint import python_command
from cmcl.run.rundir import RunDirectory
from services.sweeps.space import Dimension, SweepError, check_space, parse_search, set_flag
from services.sweeps.trial import FINISHED, OBJECTIVES, STOPPED, SweepSettings, sweep_trainable

GRACE_FRACTION = 0.25  # ASHA's first rung: this share of the trial's budget (training seconds, else episodes)
REDUCTION_FACTOR = 3  # ASHA: the share of trials 1/3 kept at each rung
EXPERIMENT = "tune"  # Tune's experiment folder inside the sweep's
SWEEP_FILE = "sweep.json"


def add_tune_flags(parser: argparse.ArgumentParser) -> None:
    """The flags of `python -m cmcl tune`."""
    parser.add_argument("--config", help="TOML experiment file every trial starts from (default: the built-in "
                                         "defaults)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="a fixed setting of every trial (repeatable)")
    parser.add_argument("--search", action="append", default=[], metavar="KEY=DISTRIBUTION",
                        help="a searched key: loguniform(a,b), uniform(a,b), randint(a,b) (both ends included) or "
                             "choice(x,y,...) (repeatable)")
    parser.add_argument("--trials", type=int, default=8, help="trials to run (default 8)")
    parser.add_argument("--objective", choices=list(OBJECTIVES), default="seconds_to_coverage",
                        help="what to optimise (default seconds_to_coverage: fewer is better)")
    parser.add_argument("--coverage", type=float, default=0.9,
                        help="seconds_to_coverage's target moving average of coverage (default 0.9)")
    parser.add_argument("--max-seconds", type=float, default=None,
                        help="training seconds of each trial (default: the config's run.max_seconds); a trial that "
                             "never reaches --coverage scores this")
    parser.add_argument("--runner", choices=("inline", "service"), default="inline",
                        help="what trains each trial: the inline runner (1 CPU, default) or the service (its roles "
                             "as Ray actors, the CPUs they request reserved per trial)")
    parser.add_argument("--seeds", type=int, default=1,
                        help="runs per trial, one after the other at run.seed + 0, 1, ...; the trial scores their "
                             "median seconds (mean held-out value) (default 1)")
    parser.add_argument("--address", default=None, help="Ray cluster to join (default: an embedded Ray)")
    parser.add_argument("--resume", metavar="DIR", default=None, help="go on with the sweep in DIR after a stop")
    parser.add_argument("--out", metavar="DIR", default=None, help="the sweep's folder (required for a new sweep)")
    parser.add_argument("--quiet", action="store_true", help="no Tune status lines; the table at the end stays")


def new_sweep(args: argparse.Namespace) -> tuple[SweepSettings, list[Dimension], int]:
    """The settings, search space and trial count of a new sweep from its flags, every one checked (SweepError
    or ConfigError naming the flag and the value) before anything is written."""
    if args.out is None:
        raise SweepError("--out DIR is required: the folder of the sweep's runs and results")
    out = Path(args.out).resolve()
    if (out / SWEEP_FILE).exists():
        raise SweepError(f"--out {args.out} already holds a sweep: go on with --resume {args.out}, or choose another "
                         "folder")
    if args.trials < 1:
        raise SweepError(f"--trials must be a positive integer, got {args.trials}")
    if not 0 < args.coverage <= 1:
        raise SweepError(f"--coverage must lie in (0, 1], got {args.coverage}")
    if args.seeds < 1:
        raise SweepError(f"--seeds must be a positive integer (runs per trial), got {args.seeds}")
    if args.max_seconds is not None and not args.max_seconds > 0:
        raise SweepError(f"--max-seconds must be a positive number of seconds, got {args.max_seconds}")
    if not args.search:
        raise SweepError("give at least one --search KEY=DISTRIBUTION, e.g. --search "
                         "maddpg.actor_lr=loguniform(1e-4,1e-2)")
    dimensions = [parse_search(text) for text in args.search]
    reserved = {"run.dir": "each trial's run directory is DIR/runs/<trial id>"}
    if args.objective == "seconds_to_coverage":
        reserved["run.stop_coverage"] = "--coverage"
    if args.max_seconds is not None:
        reserved["run.max_seconds"] = "--max-seconds"
    config_file = str(Path(args.config).resolve()) if args.config else None
    if args.seeds > 1:
        reserved["run.seed"] = "--seeds: each trial's runs take run.seed + 0, 1, ..."
    if args.runner == "service":
        reserved["service.metrics_port"] = "each service trial serves its metrics on a free port"
    config = check_space(dimensions, config_file, tuple(args.overrides), reserved, args.runner)
    budget = args.max_seconds if args.max_seconds is not None else config.run.max_seconds
    if args.objective == "seconds_to_coverage" and not budget:
        raise SweepError("--objective seconds_to_coverage scores a trial that never reaches --coverage by its time "
                         "budget: give --max-seconds S (or run.max_seconds in the config)")
    settings = SweepSettings(config_file, tuple(args.overrides), args.objective, args.coverage, float(budget),
                             str(out), args.runner, args.seeds)
    return settings, dimensions, args.trials


def tune_command(args: argparse.Namespace) -> int:
    """Run, or resume, one sweep (see the module docstring for the exit codes)."""
    try:
        if args.resume:
            folder = Path(args.resume).resolve()
            if not (folder / SWEEP_FILE).is_file():
                raise SweepError(f"--resume {args.resume}: no sweep there (no {SWEEP_FILE})")
            stored = json.loads((folder / SWEEP_FILE).read_text())
            settings = SweepSettings.from_json(stored["settings"])
            dimensions, trials = [parse_search(t) for t in stored["search"]], int(stored["trials"])
        else:
            settings, dimensions, trials = new_sweep(args)
    except (ConfigError, SweepError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    sweep = Path(settings.sweep_dir)
    if not args.resume:
        sweep.mkdir(parents=True, exist_ok=True)
        record = {"settings": settings.to_json(), "search": [d.text for d in dimensions], "trials": trials}
        atomic_write_bytes(sweep / SWEEP_FILE, json.dumps(record, indent=2).encode())
    try:
        owned = join_or_start_ray(args.address)
    except ConnectionError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    previous = signal.getsignal(signal.SIGINT)  # Tune installs its own (a Ctrl-C stops the sweep in order)
    try:
        grid = _fit(settings, dimensions, trials, resume=bool(args.resume), quiet=args.quiet)
        return _report(settings, dimensions, grid)
    finally:
        signal.signal(signal.SIGINT, previous)
        if owned:
            from services.launch import stderr_to, stop_ray

            with stderr_to(sweep / "ray_shutdown.log"):
                stop_ray()


def join_or_start_ray(address: str | None) -> bool:
    """Join `address`, or keep the Ray this process has, or start an embedded one (with the reaper); True when this
    call started or joined it (the caller stops it), False when it was there. ConnectionError (one line) when the
    cluster does not answer or the embedded Ray does not start."""
    import ray

    from services.launch import check_cluster_reachable, start_ray, unblock_stop_signals
    from services.runtime.reaper import start_reaper

    if ray.is_initialized():
        return False
    try:
        if address:
            check_cluster_reachable(address)
        else:
            start_reaper()
        start_ray(address, None)
    finally:
        unblock_stop_signals()  # start_ray kept Ray's own processes deaf to a Ctrl-C of the terminal
    return True


def _fit(settings: SweepSettings, dimensions: list[Dimension], trials: int, resume: bool, quiet: bool) -> Any:
    """Tune's results of the sweep: a new Tuner (Optuna search, ASHA scheduler), or the stored one restored."""
    from ray import tune
    from ray.tune.schedulers import ASHAScheduler
    from ray.tune.search.optuna import OptunaSearch

    trainable = sweep_trainable(settings)
    path = Path(settings.sweep_dir) / EXPERIMENT
    if resume and tune.Tuner.can_restore(str(path)):
        return tune.Tuner.restore(str(path), trainable, resume_unfinished=True, resume_errored=True).fit()
    objective, config = OBJECTIVES[settings.objective], settings.base_config()
    # a trial's clock runs over its seeds one after the other: its whole budget is the seeds' budgets summed
    time_attr, budget = ("training_s", settings.budget_s * settings.seeds) if settings.budget_s else \
        ("episodes", config.run.episodes * settings.seeds)
    # max_t past the budget: a trial's own budget ends it (summary "budget"), not the scheduler
    scheduler = ASHAScheduler(time_attr=time_attr, metric="training_ma", mode="max", max_t=2 * budget,
                              grace_period=budget * GRACE_FRACTION, reduction_factor=REDUCTION_FACTOR)
    searcher = OptunaSearch(metric="objective", mode=objective.mode, seed=config.run.seed)
    tuner = tune.Tuner(trainable, param_space={d.key: d.domain() for d in dimensions},
                       tune_config=tune.TuneConfig(search_alg=searcher, scheduler=scheduler, num_samples=trials,
                                                   reuse_actors=False),
                       run_config=tune.RunConfig(name=EXPERIMENT, storage_path=str(settings.sweep_dir),
                                                 verbose=0 if quiet else 1, log_to_file=True))
    return tuner.fit()


def _rows(settings: SweepSettings, dimensions: list[Dimension], grid: Any) -> list[dict[str, Any]]:
    """One row per trial: its id, params, objective, episodes, training seconds and how it ended (Tune's error, or
    "unfinished" when the sweep stopped before it did, else its run's summary.json), best first; unscored trials
    last."""
    from ray.tune import ExperimentAnalysis

    statuses = {t.trial_id: t.status for t in ExperimentAnalysis(str(Path(settings.sweep_dir) / EXPERIMENT)).trials}
    rows = []
    for result in grid:
        metrics = result.metrics or {}
        trial = str(metrics.get("trial_id") or Path(result.path).name.split("_")[1])
        if result.error:
            ended = f"error: {str(result.error).strip().splitlines()[-1]}"
        elif statuses.get(trial) not in ("TERMINATED", "ERROR"):
            ended = "unfinished"
        else:
            ended = trial_ended([RunDirectory(p).summary().get("ended", "") for p in settings.seed_paths(trial)])
        row = {"trial": trial, "params": {d.key: (result.config or {}).get(d.key) for d in dimensions},
               "objective": metrics.get("objective"), "episodes": metrics.get("episodes"),
               "seconds": metrics.get("training_s"), "ended": ended, "run_dir": str(settings.seed_paths(trial)[0])}
        if settings.seeds > 1:
            row.update(seed_objectives=metrics.get("seed_objectives"),
                       run_dirs=[str(p) for p in settings.seed_paths(trial)])
        rows.append(row)
    sign = 1.0 if OBJECTIVES[settings.objective].mode == "min" else -1.0
    return sorted(rows, key=lambda r: (r["objective"] is None or r["ended"].startswith("error"),
                                       sign * (r["objective"] or 0.0), r["trial"]))


def trial_ended(endings: list[str]) -> str:
    """How a trial ended from its seeds' runs' endings (summary.json "ended"; "" for a seed not trained): the one
    run's; of several, "solved" when every seed solved, "stopped_by_sweep" when the sweep stopped one, "" while a
    seed is untrained, else "budget" (a seed ran out of its budget or plateaued)."""
    if len(endings) == 1:
        return endings[0]
    if STOPPED in endings:
        return STOPPED
    if "" in endings:
        return ""
    return "solved" if all(e == "solved" for e in endings) else "budget"


def _cell(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return "-" if value is None else str(value)


def results_table(rows: list[dict[str, Any]], objective: str) -> str:
    """The trials as a fixed-width text table (columns: trial, each param, objective, episodes, seconds, ended)."""
    keys = list(rows[0]["params"]) if rows else []
    header = ["trial", *keys, objective, "episodes", "seconds", "ended"]
    body = [[r["trial"], *(_cell(r["params"][k]) for k in keys), _cell(r["objective"]), _cell(r["episodes"]),
             _cell(r["seconds"]), r["ended"]] for r in rows]
    widths = [max(len(str(line[i])) for line in [header, *body]) for i in range(len(header))]
    return "\n".join("  ".join(str(c).ljust(w) for c, w in zip(line, widths, strict=True)).rstrip()
                     for line in [header, *body])


def _report(settings: SweepSettings, dimensions: list[Dimension], grid: Any) -> int:
    """Print and write the results table and the best trial's settings; the exit code of the sweep."""
    sweep = Path(settings.sweep_dir)
    rows = _rows(settings, dimensions, grid)
    print(results_table(rows, settings.objective))
    atomic_write_bytes(sweep / "results.json", json.dumps(rows, indent=2).encode())
    scored = [r for r in rows if r["objective"] is not None and r["ended"] in FINISHED + (STOPPED,)]
    if scored:
        best = scored[0]
        flags = [set_flag(key, value) for key, value in best["params"].items()]
        record = {"objective": settings.objective, "value": best["objective"], "trial": best["trial"],
                  "params": best["params"], "set_flags": flags, "run_dir": best["run_dir"]}
        atomic_write_bytes(sweep / "best.json", json.dumps(record, indent=2).encode())
        shutil.copyfile(Path(best["run_dir"]) / "config.toml", sweep / "best_config.toml")
        print(f"best: trial {best['trial']}, {settings.objective} = {_cell(best['objective'])}; its settings "
              f"(also {sweep / 'best.json'}, its whole config {sweep / 'best_config.toml'}):")
        print(" ".join(flags))
    if any(r["ended"] == "unfinished" for r in rows):
        print(f"the sweep stopped before every trial finished. Resume with: {python_command()} -m cmcl tune "
              f"--resume {sweep}")
        return 130
    return 1 if any(r["ended"].startswith("error") for r in rows) else 0

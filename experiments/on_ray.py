"""A grid's runs as Ray Tune trials: the execution path of `python -m cmcl tune`, so a grid runs on one machine's
embedded Ray or on a cluster unchanged (`python -m experiments run GRID --ray [--address ADDR]`).

Each run still trains as `experiments.runner.run_one` trains it (its own `python -m cmcl train | resume` subprocess,
the same summary and provenance), inside a Tune trial of 1 CPU; at most `jobs` trials at a time. Resume rule: the
grid runner's own, unchanged: a run whose summary exists is not submitted, a run whose folder holds a checkpoint
resumes from it; so rerunning the command after a stop goes on (Tune's experiment folder, `<results>/tune/`, is only
Tune's log of this attempt). On a cluster the results folder must be on storage every node sees, and every node
needs this checkout at the same path. Service-runner runs start a Ray of their own and are refused here in one line.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

from experiments.run_spec import Run
from experiments.runner import run_one, runs_to_do
from experiments.store import ResultsStore

EXPERIMENT = "tune"  # Tune's experiment folder inside the results folder


class GridOnRayError(ValueError):
    """A grid that cannot run as Tune trials (one line naming the run and why)."""


def check_runs(runs: list[Run]) -> None:
    """Refuse runs that cannot train inside a Tune trial: a service run (it starts a Ray of its own)."""
    service = [r.id for r in runs if r.mode == "service"]
    if service:
        raise GridOnRayError(f"--ray trains inline runs only (a service run starts its own Ray): {service[0]} has "
                             f"mode service; run it without --ray, or choose --modes inline")


def trainable(runs: dict[str, Run], root: str) -> Callable[[dict], None]:
    """The Tune function trainable of the grid: trains config["run"] (an id of `runs`) into the store at `root`
    and reports its one-line summary."""

    def train_run(config: dict) -> None:
        from ray import tune

        started = time.perf_counter()
        line = run_one(runs[config["run"]], ResultsStore(root))
        tune.report({"done": 1, "seconds": time.perf_counter() - started, "line": line})

    return train_run


def run_grid_on_ray(runs: list[Run], store: ResultsStore, jobs: int, address: str | None,
                    report: Callable[[str], None] = print) -> int:
    """Train every run of `runs` without a summary in `store` as Tune trials, `jobs` at a time, on an embedded Ray
    (or the cluster at `address`, or the Ray this process has). Returns the number of runs that failed (each
    named); the CSV is rebuilt at the end. Raises GridOnRayError (before any run) for runs it cannot train."""
    check_runs(runs)
    todo = runs_to_do(runs, store, report, ", as Ray Tune trials")
    if not todo:
        return 0
    from ray import tune

    from services.launch import stderr_to, stop_ray
    from services.sweeps.tune import join_or_start_ray

    owned = join_or_start_ray(address)
    try:
        tuner = tune.Tuner(
            tune.with_resources(trainable({r.id: r for r in todo}, str(Path(store.root).resolve())), {"cpu": 1}),
            param_space={"run": tune.grid_search([r.id for r in todo])},
            tune_config=tune.TuneConfig(max_concurrent_trials=jobs, reuse_actors=False),
            run_config=tune.RunConfig(name=EXPERIMENT, storage_path=str(Path(store.root).resolve()), verbose=0,
                                      log_to_file=True))
        results = tuner.fit()
    finally:
        if owned:
            with stderr_to(Path(store.root) / "ray_shutdown.log"):
                stop_ray()
    failed = 0
    for result in results:
        run_id = (result.config or {}).get("run", "?")
        if result.error is not None:
            failed += 1
            report(f"{run_id} FAILED: {str(result.error).strip().splitlines()[-1]}")
        else:
            report(str((result.metrics or {}).get("line", f"{run_id} done")))
    store.write_csv()
    return failed

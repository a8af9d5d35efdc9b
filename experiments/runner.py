"""The one runner of learning runs: each run trains in its own subprocess, which dies with the runner.

Resume rule: a run whose summary exists is skipped; a run whose folder holds a checkpoint is resumed from its
newest one (`python -m cmcl resume DIR --runner inline|service`: both runners write and resume the same checkpoints;
its clock goes on from the checkpoint, so seconds stay comparable, and a wall-clock budget is given as what is left of
it, `remaining_budget`: run.max_seconds is each command's); any other run starts afresh (`python -m cmcl train
--runner inline|service ... --overwrite`: a folder without a checkpoint holds nothing worth keeping). Both runners
keep the same cadences: a progress row every 2 s, a checkpoint every service.checkpoint_every_s seconds. A folder
holding the inline runner's checkpoints of before 8dbaee8 (checkpoints/ckpt_*.pt) is refused by the resume in one
line (cmcl.run.flags.open_run): the run is reported failed, and the grid goes on.

Children die with the runner: each is started with PR_SET_PDEATHSIG = SIGKILL (Linux prctl, set in the child
before exec), so a runner killed by any signal, SIGKILL included, leaves no orphan training that a rerun's resume
would race on the same run directory. A service run's own Ray processes are reaped by the launcher's reaper
(services/runtime/reaper.py) when the launcher dies. A failed run is reported and the grid goes on; a rerun retries it.
"""

from __future__ import annotations

import ctypes
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

from cmcl.run.provenance import LoadSampler
from cmcl.run.rundir import RunDirectory
from experiments.measures import summarise
from experiments.provenance import run_provenance
from experiments.run_spec import ROOT, Run
from experiments.store import ResultsStore

PR_SET_PDEATHSIG = 1  # linux/prctl.h


def die_with_parent(parent: int | None = None) -> Callable[[], None]:
    """A preexec_fn for subprocess: in the child, before exec, ask Linux to SIGKILL it when its parent thread goes
    (prctl PR_SET_PDEATHSIG); if the parent `parent` (default: the caller) is already gone by then, exit at once."""
    parent = os.getpid() if parent is None else parent

    def arm() -> None:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
        if os.getppid() != parent:  # the parent died between fork and prctl: no signal would ever come
            os._exit(1)

    return arm


def session_yields_like_nice(autogroup: Path = Path("/proc/self/autogroup")) -> bool:
    """Give this process's scheduling autogroup its own nice value, when it leads its own session; True if set.

    Linux (CONFIG_SCHED_AUTOGROUP, on by default) shares the CPU fairly between sessions first, and `nice` only
    orders processes within a session. A grid started with `setsid nice -n 19 python -m experiments run ...` was
    measured here taking a full core's share against the user's nice-0 work in another session (its two training
    processes at 61% and 46% of the CPU while three nice-0 runs got 4-8% each). Its autogroup at nice 19 makes it
    yield as the nice value says. Only a session leader does this: in a shell's session it would nice the shell's
    other jobs as well."""
    nice = os.nice(0)
    if nice <= 0 or os.getsid(0) != os.getpid() or not autogroup.exists():
        return False
    try:
        autogroup.write_text(str(nice))
    except OSError:  # a kernel without autogroups, or one that refuses: nice alone, as before
        return False
    return True


def command(run: Run, run_path: Path) -> list[str]:
    """The command line that trains `run` in `run_path`: a resume when the folder holds a checkpoint, else a fresh
    start from the run's config file with its overrides; on the run's runner (`run.mode`: inline or service)."""
    # inline: no evaluation at the end (the summary makes its own, experiments.measures); the service's runs keep
    # make run's command as it is
    runner_flags = ["--no-eval"] if run.mode == "inline" else ["--metrics-port", "0"]
    if run_path.exists() and not run.stages:  # (the stages command resumes by itself: cmcl/run/agent_stages.py)
        if RunDirectory.open(run_path).runners():  # a checkpoint exists: resumed on the run's own runner
            budget = max_seconds_of(run)
            left = [] if not budget else ["--set", f"run.max_seconds={remaining_budget(run_path, budget)!r}"]
            return [sys.executable, "-m", "cmcl", "resume", str(run_path), *left, "--runner", run.mode, "--quiet",
                    *runner_flags]
    sets = [f"run.seed={run.seed}", f"run.dir={run_path}", f"run.episodes={run.budget}"]
    if run.prey_algorithm is not None:
        sets.append(f"teams.prey.algorithm={run.prey_algorithm}")
    if run.stop_coverage is not None:
        sets.append(f"run.stop_coverage={run.stop_coverage}")
    if run.max_seconds is not None:
        sets.append(f"run.max_seconds={run.max_seconds}")
    sets += run.sets
    config_file = ROOT / "configs" / (run.config or f"{run.task}_{run.algorithm}.toml")
    config = [] if run.task == "own_env" and run.config is None else ["--config", str(config_file)]  # own envs: sets
    set_flags = [a for s in sets for a in ("--set", s)]
    if run.stages:
        budgets = ["--stage-episodes", *map(str, run.stage_episodes)] if run.stage_episodes else []
        return [sys.executable, "-m", "cmcl", "stages", "--runner", run.mode, "--agents", *map(str, run.stages),
                *budgets, *config, *set_flags, "--quiet", *runner_flags]
    return [sys.executable, "-m", "cmcl", "train", "--runner", run.mode, *config, *set_flags, "--overwrite",
            "--quiet", *runner_flags]


def max_seconds_of(run: Run) -> float:
    """The run's wall-clock budget, seconds: its max_seconds, else a run.max_seconds among its sets (the last one);
    0.0 when it has none."""
    budget = run.max_seconds or 0.0
    for item in run.sets:
        if item.startswith("run.max_seconds="):
            budget = float(item.split("=", 1)[1])
    return float(budget)


def remaining_budget(run_path: Path, budget: float) -> float:
    """What is left of a `budget` of training seconds in an interrupted run: the budget less the training clock of
    its newest metrics row (both runners' clocks go on over resumes), at least 1 ms (run.max_seconds = 0 would mean
    no budget at all)."""
    spent = max((float(r.get("elapsed_s", 0.0)) for r in RunDirectory.open(run_path).rows()), default=0.0)
    return max(float(budget) - spent, 0.001)


def train(run: Run, store: ResultsStore) -> Path:
    """Train (or resume) one run in a subprocess that dies with this process; returns its run directory.
    Raises subprocess.CalledProcessError when the run fails."""
    run_path = store.runs_dir(run.id)
    subprocess.run(command(run, run_path), cwd=ROOT, check=True, stdout=subprocess.DEVNULL,
                   preexec_fn=die_with_parent())
    return run_path


def run_one(run: Run, store: ResultsStore) -> str:
    """Train, summarise and store one run (a prefix reference only reads its source run); returns a one-line
    report. The summary carries its provenance (`experiments.provenance.run_provenance`): the commit and versions of
    this checkout, the load over the training, the commits the run directory's segments recorded and the training
    fingerprint of the run's settings."""
    started = time.perf_counter()
    if run.source is not None:
        summary = summarise(run, store.runs_dir(run.source), upto=run.budget)
        summary["provenance"] = run_provenance(run, store.runs_dir(run.source), None)
    else:
        with LoadSampler() as load:
            run_path = train(run, store)
        summary = summarise(run, run_path)
        summary["provenance"] = run_provenance(run, run_path, load.summary())
    store.write(summary)
    keys = ("held_out_coverage", "held_out_success", "episodes_to_90", "win_vs_trained_prey", "wall_s", "ess_mean")
    return f"{run.id} done in {time.perf_counter() - started:.0f} s: " + \
        ", ".join(f"{k}={summary[k]}" for k in keys if k in summary)


def runs_to_do(runs: list[Run], store: ResultsStore, report: Callable[[str], None], how: str = "") -> list[Run]:
    """The runs of `runs` without a summary in `store`, in order, said in one line (`how`: e.g. ", as Ray Tune
    trials")."""
    finished = store.finished()
    todo = [r for r in runs if r.id not in finished]
    report(f"{len(todo)} runs to do{how}: {' '.join(r.id for r in todo)}")
    return todo


def run_grid(runs: list[Run], store: ResultsStore, jobs: int = 1, report: Callable[[str], None] = print) -> int:
    """Run every run of `runs` without a summary in `store`, `jobs` at a time, submitted in the given order; the
    CSV is rebuilt after each. Returns the number of runs that failed (each is reported, the others go on)."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    if session_yields_like_nice():
        report(f"the session's autogroup runs at nice {os.nice(0)}: the grid yields to other sessions")
    todo = runs_to_do(runs, store, report)
    failed = 0
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        futures = {pool.submit(run_one, r, store): r.id for r in todo}
        for future in as_completed(futures):
            try:
                report(future.result())
            except Exception as err:  # one failed run must not stop the others; a rerun retries it
                failed += 1
                report(f"{futures[future]} FAILED: {type(err).__name__}: {err}")
            store.write_csv()
    return failed

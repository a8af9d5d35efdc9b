"""One trial of a sweep (`python -m cmcl tune`): one run of the sweep's runner in the sweep's folder, reported to
Ray Tune at every progress row of its metrics.jsonl and at its end.

A trial is `python -m cmcl train --runner R --quiet --no-eval` in a Tune actor: on the inline runner every role in
the actor's own process, 1 CPU (torch on one thread); on the service runner every role a Ray actor inside the trial's
placement group, which reserves the CPUs the roles request (`trial_resources`, the launcher's own count) while the
trial's actor, the supervisor's loop, reserves none (as the launcher's driver), and the metrics endpoint on a free port.
The same checks and run directory (`cmcl.run.flags.train_in_run`), `<sweep>/runs/<trial id>/` with its config.toml,
metrics.jsonl, checkpoints and summary.json (with its provenance). The run directory it writes is watched
(`ObservedRunDirectory`): each episode row feeds the moving average of the trial's measure, each progress row (every
2 s) is one report, so that the scheduler (ASHA) can stop the trial early. A trial the scheduler stops (or the sweep,
on Ctrl-C) ends as a run stopped by a signal does: drained, every role checkpointed, summary.json written ("ended":
"stopped_by_sweep"); on `--resume` Tune restarts the trials left unfinished, and each resumes its own run directory
from its newest checkpoint (the replay otherwise) instead of starting over.

Every report carries (`TrialProgress.metrics`):
    objective     the trial's score if it ended now: seconds_to_coverage, the training seconds at which the moving
                  average of coverage over run.smoothing_window episodes first reached --coverage, else the budget
                  (--max-seconds: the worst score); held_out_coverage / held_out_success, the training moving
                  average of that measure until the last report, which holds the held-out evaluation's value
                  (HELD_OUT_EPISODES worlds never trained on, cmcl.run.evaluate)
    training_ma   the moving average of the objective's measure over the last run.smoothing_window training
                  episodes, in [0, 1] (what the scheduler compares)
    episodes, training_s   the run's episodes and training seconds (its clock, over every segment of a resumed run)
"""

from __future__ import annotations

import json
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from cmcl.config import Config, load_config
from cmcl.config.runners import Runner
from cmcl.progress.rows import window_mean
from cmcl.run.flags import RunRequest, resume_point, train_in_run
from cmcl.run.rundir import RunDirectory

HELD_OUT_EPISODES = 200  # worlds of a held-out objective's evaluation (the batched twins play them at once)
STOP_GRACE_S = 120.0  # how long a stopped trial's actor waits for its run to checkpoint and write its summary
FINISHED = ("solved", "budget", "plateau")  # how a run that a restored sweep does not train again ended
STOPPED = "stopped_by_sweep"  # summary.json's "ended" of a run the scheduler (or the sweep's stop) ended


@dataclass(frozen=True)
class Objective:
    """What a sweep optimises. mode: "min" or "max"; measure: the episode statistic whose training moving average
    the scheduler compares ("coverage", "success"); held_out: scored by a held-out evaluation at the end."""

    mode: str
    measure: str
    held_out: bool


OBJECTIVES = {"seconds_to_coverage": Objective("min", "coverage", False),
              "held_out_coverage": Objective("max", "coverage", True),
              "held_out_success": Objective("max", "success", True)}


@dataclass(frozen=True)
class SweepSettings:
    """What every trial of one sweep shares (stored as the sweep folder's sweep.json, read back on --resume).

    config_file: the preset (absolute path; None: the built-in defaults); overrides: its fixed `--set` strings;
    objective: a key of OBJECTIVES; coverage: seconds_to_coverage's target, in (0, 1]; budget_s: each trial's
    training seconds (run.max_seconds; 0: none); sweep_dir: the sweep's folder (absolute); runner: what trains each
    trial, "inline" or "service" (a sweep.json written before the choice existed: inline); seeds: the runs of each
    trial, one after the other at run.seed + 0, 1, ... (`seed_paths`), its objective their median seconds or mean
    held-out value (`combined`)."""

    config_file: str | None
    overrides: tuple[str, ...]
    objective: str
    coverage: float
    budget_s: float
    sweep_dir: str
    runner: Runner = "inline"
    seeds: int = 1

    def trial_sets(self, run_path: Path, seed: int | None = None) -> tuple[str, ...]:
        """The overrides the sweep adds to every new run of a trial: its run.dir, its run.seed (`seed`; None: the
        config's), the coverage stop of seconds_to_coverage (training past it is not scored), the budget, and on the
        service a free port for its metrics endpoint (the trials run side by side)."""
        sets = [f"run.dir={json.dumps(str(run_path))}"]
        if seed is not None:
            sets.append(f"run.seed={seed}")
        if self.runner == "service":
            sets.append("service.metrics_port=0")
        if self.objective == "seconds_to_coverage":
            sets.append(f"run.stop_coverage={self.coverage!r}")
        if self.budget_s:
            sets.append(f"run.max_seconds={self.budget_s!r}")
        return tuple(sets)

    def base_config(self) -> Config:
        """The config every trial starts from: the preset with the fixed overrides."""
        return load_config(self.config_file, self.overrides)

    def run_path(self, trial_id: str) -> Path:
        """The trial's folder: its run directory, or with several seeds the folder of their run directories."""
        return Path(self.sweep_dir) / "runs" / trial_id

    def seed_paths(self, trial_id: str) -> list[Path]:
        """The run directories of the trial's seeds, in training order: the trial's folder for one seed, else
        <trial folder>/s<k> for k = 0 .. seeds - 1 (trained at run.seed + k)."""
        if self.seeds == 1:
            return [self.run_path(trial_id)]
        return [self.run_path(trial_id) / f"s{k}" for k in range(self.seeds)]

    def combined(self, scores: list[float]) -> float:
        """A trial's objective from its seeds' scores: the median of seconds_to_coverage (a seed that never reached
        the target counts its budget), the mean of a held-out measure."""
        values = sorted(scores)
        if not OBJECTIVES[self.objective].held_out:
            mid = len(values) // 2
            return values[mid] if len(values) % 2 else (values[mid - 1] + values[mid]) / 2
        return sum(values) / len(values)

    def to_json(self) -> dict[str, Any]:
        return {**asdict(self), "overrides": list(self.overrides)}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> SweepSettings:
        return cls(**{**data, "overrides": tuple(data["overrides"])})


class TrialProgress:
    """The trial's view of its run, fed the metrics rows in the order they are written (`observe`); `report` is
    called with `metrics()` at every progress row until the sweep stops the trial (`report` raising SystemExit, as
    ray.tune.report does then): `stopped` becomes true and the run is asked to stop (`stop_requested`)."""

    def __init__(self, settings: SweepSettings, config: Config, report: Callable[[dict[str, Any]], None] | None):
        self.objective = OBJECTIVES[settings.objective]
        self.coverage, self.budget_s = settings.coverage, settings.budget_s
        self.window: deque[dict[str, Any]] = deque(maxlen=config.run.smoothing_window)
        self.report = report
        self.episodes, self.training_s = 0, 0.0
        self.reached_s: float | None = None  # training seconds when the coverage average reached the target
        self.held_out: dict[str, float] = {}
        self.stopped = False

    def observe(self, row: Mapping[str, Any]) -> None:
        """Take one metrics row: an episode row moves the window, a progress row is reported."""
        if row.get("kind") == "episode":
            self.window.append(dict(row))
            self.episodes, self.training_s = int(row["episodes"]), float(row.get("elapsed_s", self.training_s))
            full = len(self.window) == self.window.maxlen
            coverage = window_mean(self.window, "coverage")
            if self.reached_s is None and full and coverage is not None and coverage >= self.coverage:
                self.reached_s = self.training_s
        elif row.get("kind") == "progress":
            self.training_s = float(row.get("elapsed_s", self.training_s))
            self.send()

    def replay(self, rows: Iterable[Mapping[str, Any]]) -> None:
        """Take the rows an earlier segment of the run wrote, reporting none of them."""
        report, self.report = self.report, None
        try:
            for row in rows:
                self.observe(row)
        finally:
            self.report = report

    def stop_requested(self) -> bool:
        """Whether the run should stop now: the sweep stopped the trial, or seconds_to_coverage's target was
        reached (its score is known; the run's own run.stop_coverage check, once per collected report, can miss a
        crossing within one)."""
        return self.stopped or (not self.objective.held_out and self.reached_s is not None)

    def send(self) -> None:
        """Report `metrics()` unless the trial has been stopped; a stop (SystemExit from the report) is noted."""
        if self.report is None or self.stopped:
            return
        try:
            self.report(self.metrics())
        except SystemExit:  # ray.tune.report's way of ending a trial the scheduler stopped
            self.stopped = True

    def training_ma(self) -> float:
        return window_mean(self.window, self.objective.measure) or 0.0

    def score(self) -> float:
        """The objective's value now (see the module docstring)."""
        if self.objective.held_out:
            return self.held_out.get(self.objective.measure, self.training_ma())
        return self.reached_s if self.reached_s is not None else self.budget_s

    def metrics(self) -> dict[str, Any]:
        return {"objective": self.score(), "training_ma": self.training_ma(), "episodes": self.episodes,
                "training_s": self.training_s, "reached_s": self.reached_s,
                **{f"held_out_{k}": v for k, v in self.held_out.items()}}


class ObservedRunDirectory(RunDirectory):
    """A run directory whose every metrics row, once appended, is also handed to `observe`."""

    def __init__(self, path: str | Path, observe: Callable[[Mapping[str, Any]], None]):
        super().__init__(path)
        self.observe = observe

    def log(self, row: Mapping[str, Any]) -> None:
        super().log(row)
        self.observe(row)


class TrialFailed(RuntimeError):
    """A trial's run ended with an error exit (its one-line error is in the trial's stderr file)."""


def held_out(config: Config, run_dir: RunDirectory) -> dict[str, float]:
    """Coverage and success of the run's newest verified policy on HELD_OUT_EPISODES held-out worlds."""
    from cmcl.run.evaluate import evaluate_policy, load_policy  # torch

    policy = run_dir.newest_policy()
    result = evaluate_policy(config, None if policy is None else load_policy(config, policy), HELD_OUT_EPISODES)
    return {key: float(result[key]) for key in ("coverage", "success") if key in result}


def run_trial(params: Mapping[str, Any], settings: SweepSettings, trial_id: str,
              report: Callable[[dict[str, Any]], None]) -> dict[str, Any]:
    """Train (or, restored, resume or only re-read) the runs of one trial with the sampled `params` ({dotted key:
    value}), its seeds one after the other (`SweepSettings.seed_paths`); `report` gets the metrics at every progress
    row and at the end: the objective combined over the seeds so far and the current one (`combined`), the episodes
    and training seconds summed over them, the current seed's training average, and at the end every seed's score
    ("seed_objectives"). Returns the last metrics. Raises SystemExit once the sweep has stopped the trial (after the
    current run's summary is written; later seeds are not trained), TrialFailed when a run ends with an error exit."""
    import torch

    torch.set_num_threads(1)
    base_seed = load_config(settings.config_file, settings.overrides).run.seed if settings.seeds > 1 else None
    scores: list[float] = []
    episodes, seconds = 0, 0.0
    progress: TrialProgress | None = None
    for k, run_path in enumerate(settings.seed_paths(trial_id)):
        done, before = tuple(scores), (episodes, seconds)

        def seed_report(metrics: dict[str, Any], done: tuple[float, ...] = done,
                        before: tuple[int, float] = before) -> None:
            report({**metrics, "objective": settings.combined([*done, metrics["objective"]]),
                    "episodes": before[0] + metrics["episodes"], "training_s": before[1] + metrics["training_s"]})

        seed = None if base_seed is None else base_seed + k
        progress = train_seed(params, settings, trial_id, run_path, seed, seed_report)
        scores.append(progress.score())
        episodes, seconds = episodes + progress.episodes, seconds + progress.training_s
    assert progress is not None  # seeds >= 1
    metrics = {**progress.metrics(), "objective": settings.combined(scores), "episodes": episodes,
               "training_s": seconds, "seed_objectives": scores}
    report(metrics)
    return metrics


def train_seed(params: Mapping[str, Any], settings: SweepSettings, trial_id: str, run_path: Path, seed: int | None,
               report: Callable[[dict[str, Any]], None]) -> TrialProgress:
    """Train, resume or only re-read one run of a trial in `run_path` (at run.seed `seed`; None: the config's);
    `report` gets the metrics at every progress row. Returns its progress, with the held-out values of a held-out
    objective. SystemExit once the sweep stopped it (after its summary is written); TrialFailed for an error exit."""
    from services.sweeps.space import override

    earlier = RunDirectory(run_path) if (run_path / "config.toml").is_file() else None
    if earlier is not None and earlier.summary().get("ended") in FINISHED:
        request = None  # a finished run of a restored sweep: its result is read back, not trained again
    elif earlier is not None and resume_point(earlier) is not None:
        spent = max((float(r.get("elapsed_s", 0.0)) for r in earlier.rows()), default=0.0)
        left = () if not settings.budget_s else (f"run.max_seconds={max(settings.budget_s - spent, 0.001)!r}",)
        request = RunRequest(settings.runner, resume_dir=str(run_path), overrides=left, quiet=True, no_eval=True)
    else:
        sets = (*settings.overrides, *(override(k, v) for k, v in params.items()),
                *settings.trial_sets(run_path, seed))
        request = RunRequest(settings.runner, config_file=settings.config_file, overrides=sets, overwrite=True,
                             quiet=True, no_eval=True)
    watched: list[TrialProgress] = []

    def train(config: Config, run_dir: RunDirectory, _lock: Any) -> int:
        from services.launch import run_service

        progress = TrialProgress(settings, config, report)
        watched.append(progress)
        progress.replay(run_dir.rows())
        summary = run_service(config, ObservedRunDirectory(run_dir.path, progress.observe),
                              resume=bool(request.resume_dir), progress=None, stop=progress.stop_requested,
                              in_process=settings.runner == "inline")
        solved = summary.get("solved") or (progress.reached_s is not None and not progress.objective.held_out)
        ended = "solved" if solved else STOPPED if progress.stopped else "plateau" if summary.get("plateau") \
            else "budget"
        run_dir.write_summary({**{k: v for k, v in summary.items() if k != "metrics_text"}, "ended": ended,
                               "runner": settings.runner, "sweep_trial": trial_id, "sweep_params": dict(params)})
        return 0

    if request is not None:
        code = train_in_run(request, train)
        if code != 0:
            raise TrialFailed(f"the run of trial {trial_id} in {run_path} ended with exit {code} (its error line is "
                              "in the trial's stderr file)")
        progress = watched[0]
        if progress.stopped:
            raise SystemExit(0)
    else:
        progress = TrialProgress(settings, earlier.config(), None)
        progress.replay(earlier.rows())
        progress.report = report
    if progress.objective.held_out:
        run_dir = RunDirectory(run_path)
        progress.held_out = held_out(run_dir.config(), run_dir)
    return progress


def trial_resources(settings: SweepSettings, cluster_cpus: float) -> Callable[[Mapping[str, Any]], Any]:
    """What Tune reserves for a trial with the sampled `params`: 1 CPU for an inline trial; for a service trial a
    placement group of an empty head bundle (the trial's actor, the supervisor's loop, as the launcher's driver)
    and one bundle of the CPUs its roles request (services.runtime.placement.required_cpus at `cluster_cpus`, with
    the rollout workers' custom resource), into which Tune's placement group captures the roles' actors."""
    from ray.tune import PlacementGroupFactory

    from services.runtime.placement import ROLLOUT_RESOURCE_SHARE, required_cpus
    from services.sweeps.space import override

    def resources(params: Mapping[str, Any]) -> Any:
        if settings.runner == "inline":
            return PlacementGroupFactory([{"CPU": 1.0}])
        config = load_config(settings.config_file, (*settings.overrides, *(override(k, v) for k, v in params.items())))
        bundle = {"CPU": required_cpus(config, cluster_cpus)}
        if config.service.rollout_resource:
            bundle[config.service.rollout_resource] = config.service.rollout_workers * ROLLOUT_RESOURCE_SHARE
        return PlacementGroupFactory([{}, bundle])

    return resources


def sweep_trainable(settings: SweepSettings) -> Any:
    """The Tune trainable of `settings`' trials (`trial_resources` each, on the Ray this process is connected to):
    `run_trial` under Tune's function API, whose actor, when the trial is stopped, waits up to STOP_GRACE_S for the
    run to checkpoint and write its summary (Tune's own cleanup does not wait for the training thread)."""
    import ray
    from ray import tune
    from ray.train._internal.session import get_session  # the training thread of the function API
    from ray.tune.trainable.function_trainable import wrap_function

    def trial(config: dict[str, Any]) -> None:
        run_trial(config, settings, tune.get_context().get_trial_id(), tune.report)

    class SweepTrial(wrap_function(trial)):  # type: ignore[misc]
        def cleanup(self) -> None:
            session = get_session()
            thread = session.training_thread if session is not None and session.training_started else None
            super().cleanup()  # lets the training thread's blocked report raise SystemExit: the run stops in order
            if thread is not None:
                thread.join(STOP_GRACE_S)

    return tune.with_resources(SweepTrial, trial_resources(settings, ray.cluster_resources().get("CPU", 0.0)))

"""The run's own sections of a run configuration: [run] (`RunConfig`: budget, seed, output, stop rules,
bookkeeping) and [service] (`ServiceConfig`: the distributed service's actors, per-call work and resources).

Every field is declared with `documented(default, meaning, unit=..., rule=...)` (cmcl.field_docs), as in
cmcl.config.learning; each `__post_init__` runs the rules (`check_fields`) and raises `ConfigError` naming the key
and the value. Which keys only one runner honours is cmcl.config.runners. Reads nothing but its own fields.
"""

from __future__ import annotations

import os
import typing
from dataclasses import dataclass
from typing import Literal

from cmcl.config.checks import AT_LEAST_0, AT_LEAST_1, FINITE_AT_LEAST_0, POSITIVE, PROBABILITY, check_fields, rule
from cmcl.field_docs import documented

__all__ = ["PROGRESS_SIGNALS", "RunConfig", "ServiceConfig"]

ProgressSignal = Literal["critic_loss", "normalised_td", "coverage"]  # cmcl.progress.learning.SIGNALS
PROGRESS_SIGNALS: tuple[str, ...] = typing.get_args(ProgressSignal)


@dataclass(frozen=True)
class RunConfig:
    """Budget, seed, output and bookkeeping of one run."""

    episodes: int = documented(20000, "training budget", unit="episodes", rule=AT_LEAST_1)
    dir: str = documented("runs/default", "the run directory (config, metrics, checkpoints, evaluation; "
                          "cmcl.run.rundir)", unit="path", rule=rule("must be a non-empty path", bool))
    seed: int = documented(0, "seed of the run's random generators (worlds, networks, sampling)", rule=AT_LEAST_0)
    smoothing_window: int = documented(100, "window of the curves' and progress lines' moving averages",
                                       unit="episodes", rule=AT_LEAST_1)
    stop_coverage: float = documented(0.0, "stop early once the moving average (over smoothing_window episodes) "
                                      "of final-step coverage reaches this (spread only; 0: off, train all "
                                      "run.episodes)", unit="fraction of landmarks", rule=PROBABILITY)
    max_seconds: float = documented(0.0, "wall-clock budget of this command's training, inline and in the service "
                                    "(0: none); a resumed run gets it again, and its elapsed_s goes on over every "
                                    "segment", unit="seconds", rule=FINITE_AT_LEAST_0)
    stop_progress: float = documented(
        0.0, "stop early once learning stops progressing (cmcl.progress.learning): the learning progress of "
        "progress_signal between consecutive windows of progress_window episodes stays below this for "
        "progress_patience windows (0: off). With the default signal, coverage, it is an absolute change of the "
        "window's mean coverage (0.02 separated a rising from a flat stage in "
        "lab/studies/learning_progress_windows.py, one seed). The agent-count curriculum (python -m cmcl stages) "
        "ends its stages by it",
        unit="change of coverage (coverage); relative change (critic_loss, normalised_td)", rule=FINITE_AT_LEAST_0)
    progress_signal: ProgressSignal = documented(
        "coverage", "what stop_progress reads (cmcl.progress.learning): 'coverage' = the absolute change of the "
        "mean final-step coverage (spread, or env.coverage_key); 'normalised_td' = the relative change of the "
        "critics' mean squared TD error over the variance of their TD targets (1 - R^2); 'critic_loss' = the "
        "relative change of the mean critic loss (the old default: the loss grows with the value scale, "
        "so it stays high after coverage is flat)")
    progress_window: int = documented(500, "episodes per learning-progress window (run.stop_progress)",
                                      unit="episodes", rule=AT_LEAST_1)
    progress_patience: int = documented(3, "consecutive windows below stop_progress that end the run",
                                        unit="windows", rule=AT_LEAST_1)
    init_from: str = documented(
        "", "a run directory whose newest policy initialises this new run's actors and critics "
        "(cmcl.run.warm_start; same network shapes required); '' = random initial weights. A resumed run "
        "ignores it (its checkpoint wins)", unit="path")
    carry_replay: bool = documented(
        False, "with init_from, also start with that run's replay rows (its newest checkpoint's buffer), padded to "
        "this run's agent count (cmcl.replay.agent_padding: absent agents zero and masked per row), so that the "
        "buffer holds rows of both counts (the agent-count curriculum: `python -m cmcl stages ... --set "
        "run.carry_replay=true`). Needs maddpg.networks = 'entity', task spread and algorithms maddpg or per; "
        "either runner. Off: an empty buffer")

    def __post_init__(self) -> None:
        for name in ("dir", "init_from"):  # "~/runs/x" is the user's home, as in a shell, not a folder named "~"
            value = getattr(self, name)  # (a shell leaves `--set run.dir=~/x` unexpanded: it is no assignment)
            if isinstance(value, str) and value.startswith("~"):
                object.__setattr__(self, name, os.path.expanduser(value))
        check_fields(self, "run")


@dataclass(frozen=True)
class ServiceConfig:
    """The roles and their calls (services/), read by both runners: actor counts, per-call work, rate-limiter slack,
    checkpoint cadence; and the service's own (Ray) keys, CPUs, restarts, timeouts and metrics
    (cmcl.config.runners)."""

    rollout_workers: int = documented(1, "rollout worker actors, each stepping env.num_envs worlds",
                                      unit="actors", rule=AT_LEAST_1)
    teacher_actors: int = documented(
        0, "actors sharing the K teacher folds: K = one fold each, 1 = all folds stacked in one actor; 0 = "
        "automatic: K when the cluster has at least 2K CPUs, else 1 (on 2 cores one stacked actor is 1.4x faster "
        "than K); placement policy: services.runtime.placement.teacher_groups", unit="actors", rule=AT_LEAST_0)
    updates_per_call: int = documented(16, "learner updates per learner call (batches sampled per replay call)",
                                       unit="updates", rule=AT_LEAST_1)
    fit_steps_per_call: int = documented(8, "teacher / ICM fit steps per call", unit="fit steps", rule=AT_LEAST_1)
    score_rows_per_call: int = documented(1024, "rows a teacher / the ICM rescores per call", unit="rows",
                                          rule=AT_LEAST_1)
    slack_updates: int = documented(256, "how far updates may run ahead of / behind the env-step ratio (the rate "
                                    "limiter's slack)", unit="updates", rule=AT_LEAST_1)
    call_timeout_s: float = documented(300.0, "a call in flight longer than this marks its actor hung: killed, "
                                       "restarted (0: off)", unit="seconds", rule=rule("must be >= 0 (0: off)",
                                                                                      lambda v: v >= 0))
    replay_log_fsync: bool = documented(False, "fsync every replay-log append (survives power loss; flush-only "
                                        "survives crashes)")
    recompute_every: int = documented(0, "inserts between bulk priority recomputes (0: one episode of every "
                                      "worker)", unit="inserts", rule=AT_LEAST_0)
    checkpoint_every_s: float = documented(
        60.0, "seconds between checkpoints of every role (and one at the end, and one on a graceful stop): bounds "
        "the learning a hard crash loses; measured cost at 60 s: bench/checkpoint_cadence.py", unit="seconds",
        rule=POSITIVE)
    max_restarts: int = documented(3, "restarts Ray may make of one actor after it dies", unit="restarts",
                                   rule=AT_LEAST_0)
    rollout_cpus: float = documented(0.25, "CPUs Ray reserves for each rollout worker", unit="CPUs",
                                     rule=POSITIVE)
    learner_cpus: float = documented(0.5, "CPUs Ray reserves for the learner", unit="CPUs", rule=POSITIVE)
    teacher_cpus: float = documented(0.1, "CPUs Ray reserves for each teacher actor", unit="CPUs", rule=POSITIVE)
    icm_cpus: float = documented(0.1, "CPUs Ray reserves for the ICM actor", unit="CPUs", rule=POSITIVE)
    replay_cpus: float = documented(0.25, "CPUs Ray reserves for the replay server", unit="CPUs", rule=POSITIVE)
    rollout_resource: str = documented(
        "", "a custom Ray resource the rollout workers require (0.01 of it each), to keep them on the nodes that "
        "advertise it (e.g. `ray start --resources='{\"rollout\": 100}'` on CPU worker nodes); '' = any node",
        rule=rule("must be a Ray resource name ([A-Za-z0-9_-]+)",
                  lambda v: v == "" or v.replace("_", "").replace("-", "").isalnum()))
    metrics_port: int = documented(9100, "port of the Prometheus metrics endpoint (0: pick a free port)",
                                   unit="TCP port", rule=rule("must lie in [0, 65535]", lambda v: 0 <= v <= 65535))
    metrics_host: str = documented("127.0.0.1", "address the metrics endpoint listens on", unit="host")

    def __post_init__(self) -> None:
        check_fields(self, "service")

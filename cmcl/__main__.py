"""One entry point for both runners: `python -m cmcl train | resume | evaluate | stages | status | tune | config`.

    python -m cmcl train [--runner service|inline] [--config F] [--set section.key=value ...] [--overwrite]
    python -m cmcl resume RUN_DIR [--more-episodes N] [--set ...]  (the runner that wrote RUN_DIR, by default)
    python -m cmcl evaluate RUN_DIR [--episodes 100] [--checkpoint PATH] [--random] [--no-gif]
    python -m cmcl stages --agents 2 4 8 [--stage-episodes E E E] [train's flags]   (cmcl/run/agent_stages.py)
    python -m cmcl status RUN_DIR [RUN_DIR ...]   (where each run stands, one line each: cmcl/run/status.py)
    python -m cmcl tune --config F --search KEY=DISTRIBUTION ... --trials N --out DIR [--resume DIR]
                                                 (a sweep on Ray Tune, one inline run per trial:
                                                 services/sweeps/tune.py)
    python -m cmcl config [SECTION | SECTION.KEY] [--markdown]   (every config key: meaning, unit, default, range;
                                                                 docs/CONFIG.md)

The default runner of `train` is the service on an embedded Ray: the system this project is about, what `make run`
starts, and the one that ends with the held-out evaluation and the GIF. `--runner inline` trains in this process
without Ray (Algorithm 1, the reference the service is measured against). Both write one run-directory layout
(cmcl/run/rundir.py), so `resume` and `evaluate` find the run's newest verified policy themselves.
`python -m services.launch` and `python -m cmcl.run.evaluate` remain, as aliases with the same flags
(cmcl/run/flags.py). Exit codes: 0 done, 2 bad arguments / config / run directory, 130 / 143 stopped by SIGINT / SIGTERM
after a checkpoint.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from cmcl.run.flags import (
    RUNNERS,
    RunRequest,
    RunRequestError,
    add_evaluate_flags,
    add_run_flags,
    request_from,
)
from cmcl.run.rundir import RunDirectory
from cmcl.run.status import runner_of, status_command
from cmcl.run.stopping import exit_without_teardown

DEFAULT_RUNNER = "service"
# Each runner's entry function, imported only when that runner runs: `cmcl/` never imports Ray, and `--help`
# imports no torch.
RUNNER_ENTRIES = {"inline": ("services.launch", "run_launch"), "service": ("services.launch", "run_launch")}
# the sweep's flags and entry (they import Ray)
TUNE_FLAGS, TUNE_ENTRY = ("services.sweeps.tune", "add_tune_flags"), ("services.sweeps.tune", "tune_command")


def build_parser() -> argparse.ArgumentParser:
    """The parser of `python -m cmcl`: one sub-command per verb; the run flags are those of cmcl/run/flags.py."""
    parser = argparse.ArgumentParser(prog="python -m cmcl", description=__doc__.split("\n")[0])
    verbs = parser.add_subparsers(dest="verb", required=True)
    train = verbs.add_parser("train", help="train a new run", description="Train a new run in run.dir.")
    train.add_argument("--runner", choices=RUNNERS, default=DEFAULT_RUNNER,
                       help="service (Ray; default) or inline (one process, no Ray)")
    add_run_flags(train)
    resume = verbs.add_parser("resume", help="continue a run from its newest checkpoint",
                              description="Continue the run in RUN_DIR from its newest verified checkpoint.")
    resume.add_argument("run_dir", metavar="RUN_DIR", help="a run directory written by either runner")
    resume.add_argument("--runner", choices=RUNNERS, default=None, help="default: the runner that wrote RUN_DIR")
    add_run_flags(resume, new_run=False)
    evaluate = verbs.add_parser("evaluate", help="held-out evaluation of a run's policy, a GIF, the curve",
                                description="Evaluate the newest verified policy of RUN_DIR on held-out worlds.")
    add_evaluate_flags(evaluate)
    stages = verbs.add_parser("stages", help="a curriculum over the number of agents: one run per agent count",
                              description="Train navigation with N_1 < N_2 < ... agents in turn, each stage starting "
                                          "from the networks of the one before (cmcl/run/agent_stages.py); rerun the "
                                          "same command to go on after a stop.")
    stages.add_argument("--agents", type=int, nargs="+", required=True, metavar="N", help="agent counts, increasing")
    stages.add_argument("--stage-episodes", type=int, nargs="+", default=None, metavar="E",
                        help="episode budget of each stage (default: run.episodes each)")
    stages.add_argument("--runner", choices=RUNNERS, default=DEFAULT_RUNNER,
                        help="service (Ray; default) or inline (one process, no Ray)")
    add_run_flags(stages)
    status = verbs.add_parser("status", help="where each run stands: running, ended or cut off, episodes, seconds, "
                                             "coverage, newest checkpoint",
                              description="One line per run folder, read from its files alone (nothing written, no "
                                          "Ray): cmcl/run/status.py.")
    status.add_argument("run_dirs", nargs="+", metavar="DIR", help="run folders, e.g. runs/*")
    tune = verbs.add_parser("tune", help="a sweep on Ray Tune: Optuna proposes settings, ASHA stops trials early",
                            description="Sweep config keys on Ray Tune (Optuna search, ASHA scheduler), one inline "
                                        "run per trial in OUT/runs/; a results table and the best settings as --set "
                                        "flags at the end (services/sweeps/tune.py).")
    getattr(importlib.import_module(TUNE_FLAGS[0]), TUNE_FLAGS[1])(tune)
    config = verbs.add_parser("config", help="every config key: its meaning, unit, default and allowed range",
                              description="Print every key of a run configuration (or of SECTION) with its meaning, "
                                          "unit, default and allowed range (cmcl/config/reference.py).")
    config.add_argument("section", nargs="?", metavar="SECTION",
                        help="one section, e.g. maddpg, or one key, e.g. maddpg.hidden or teams.agent.eta (default: "
                             "all)")
    config.add_argument("--markdown", action="store_true", help="Markdown tables (docs/CONFIG.md)")
    verbs.metavar = "{" + ",".join(verbs.choices) + "}"  # every verb, in the usage line too
    return parser


def run(request: RunRequest) -> int:
    """Hand `request` to its runner's entry function; returns the exit code."""
    module, function = RUNNER_ENTRIES[request.runner]
    return getattr(importlib.import_module(module), function)(request)


def main(argv: list[str] | None = None) -> int:
    """CLI entry point (see the module docstring for the verbs and the exit codes); a Ctrl-C before a runner's own
    stop handler is installed (imports, the checks of the run) ends it with one line, exit 130."""
    try:
        return _main(argv)
    except KeyboardInterrupt:
        from cmcl.run.flags import STARTUP_STOP

        print(STARTUP_STOP, file=sys.stderr)
        return 130


def _main(argv: list[str] | None) -> int:
    args = build_parser().parse_args(argv)
    if args.verb == "config":
        from cmcl.config.reference import config_command

        return config_command(args.section, args.markdown)
    if args.verb == "status":
        return status_command(args.run_dirs)
    if args.verb == "tune":
        return getattr(importlib.import_module(TUNE_ENTRY[0]), TUNE_ENTRY[1])(args)
    if args.verb == "evaluate":
        from cmcl.run.evaluate import evaluate_run

        return evaluate_run(args)
    if args.verb == "stages":
        from cmcl.run.agent_stages import run_stages

        try:
            base = request_from(args, args.runner)
        except RunRequestError as err:
            print(f"error: {err}", file=sys.stderr)
            return 2
        return run_stages(base, args.agents, args.stage_episodes, run)
    try:
        if args.verb == "resume":
            runner = args.runner or runner_of(RunDirectory.open(args.run_dir))
            request = request_from(args, runner, resume_dir=args.run_dir)
        else:
            request = request_from(args, args.runner)
    except (FileNotFoundError, RunRequestError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return run(request)


if __name__ == "__main__":
    exit_without_teardown(main())  # the exit status of sys.exit, without ~1-2 s of teardown

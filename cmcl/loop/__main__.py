"""The inline runner's command line: trains (or resumes) one run in this process and plots its learning curve.

`python -m cmcl train --runner inline` and `python -m cmcl resume DIR` (a run this runner wrote) call `run_inline`;
`python -m cmcl.loop` is their alias, with the same flags (cmcl/run_flags.py) and `--resume DIR`:
      python -m cmcl.loop --config configs/spread_cmcl.toml [--set run.episodes=40 --set run.dir=runs/smoke]
      python -m cmcl.loop --resume runs/smoke [--set run.episodes=80]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from cmcl.config import Config
from cmcl.io import codec
from cmcl.io.resume_hint import resume_command
from cmcl.io.rundir import RunDirectory
from cmcl.io.verified import CheckpointError
from cmcl.progress import solved
from cmcl.run_flags import RunRequest, alias_parser, run_alias, train_in_run
from cmcl.run_report import done_line, report_trained
from cmcl.stopping import StopSignals, exit_without_teardown

if TYPE_CHECKING:  # torch: imported by `_train` once the run directory is taken (a run in use is refused first)
    from cmcl.loop.inline import InlineLoop


def restore_newest_good(loop: InlineLoop, run_dir: RunDirectory) -> Path | None:
    """Restore the newest checkpoint that passes its checks (manifest digest, snapshot limits); each refused one
    is named on stderr and the one before it is tried. Returns the checkpoint restored, None if none passed."""
    for checkpoint in reversed(run_dir.inline_checkpoints().values()):
        try:
            loop.restore(checkpoint)
            return checkpoint
        except (CheckpointError, codec.CodecError, OSError) as err:
            print(f"checkpoint refused: {err}", file=sys.stderr)
    return None


def build_parser() -> argparse.ArgumentParser:
    """The alias's flags: those of every training command (cmcl/run_flags.py) and `--resume DIR`."""
    return alias_parser("python -m cmcl.loop", "Train (or resume) one run with the inline runner: one process, "
                                               "no Ray.")


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    return build_parser().parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """`python -m cmcl.loop`: the alias of `python -m cmcl train|resume --runner inline`."""
    return run_alias(parse_args(argv), "inline", run_inline)


def run_inline(request: RunRequest) -> int:
    """Train, or resume, one inline run; at the end the `done` line and, unless `no_eval`, the learning curve, the
    held-out evaluation and a GIF, as the service's (cmcl.run_report). Exit codes: 0 done,
    2 bad config / arguments / run directory in use / nothing to resume / training diverged / a file of the run that
    cannot be written (a full disk: said by cmcl.run_flags.train_in_run), 130 / 143 stopped by SIGINT / SIGTERM (after
    a checkpoint)."""
    return train_in_run(request, lambda config, run_dir, _lock: _train(request, config, run_dir))


def _train(request: RunRequest, config: Config, run_dir: RunDirectory) -> int:
    """Build the loop, restore it when resuming, train until done or stopped; the run directory is locked."""
    from cmcl.envs.factory import EnvFactoryError
    from cmcl.learners.warm_start import warm_start_from_config
    from cmcl.loop.inline import InlineLoop
    from cmcl.progress import TrainingDiverged

    loop = InlineLoop(config, run_dir, progress=None if request.quiet else print)
    if request.resume_dir:
        resume_dir = request.resume_dir
        try:
            checkpoint = restore_newest_good(loop, run_dir)
        except ValueError as err:  # a checkpoint of other settings (shapes, folds): older ones are alike
            print(f"error: {resume_dir} cannot resume under these settings: {err}", file=sys.stderr)
            return 2
        if checkpoint is None:
            print(f"error: {resume_dir} holds no checkpoint to resume from that passes its checks", file=sys.stderr)
            return 2
        run_dir.truncate_rows_after(loop.counters["episodes"])
        print(f"resumed from {checkpoint} at episode {loop.counters['episodes']}")
    elif config.run.init_from:
        print(f"actors and critics initialised from {warm_start_from_config(config.run.init_from, loop.maddpg)}")
        if config.run.carry_replay:
            from cmcl.carried_replay import carry_replay_rows

            loop.scoring.inserted(carry_replay_rows(loop.replay, config.run.init_from, loop.layout.entities), 0)
            print(f"replay: starts with the {loop.replay.size} rows of {config.run.init_from} "
                  f"({loop.replay.storage.absent_rows} of them with absent agents)")
    with StopSignals(notice=print) as stop:
        try:
            row = loop.run(stop=lambda: stop.requested)
        except TrainingDiverged as err:  # the last checkpoint before it stays the run's newest
            run_dir.write_summary({"runner": "inline", "ended": "diverged", **loop.counters,
                                   "elapsed_s": loop.elapsed_s, "segment_s": loop.segment_s})
            print(f"error: {err}", file=sys.stderr)
            return 2
        except EnvFactoryError as err:  # the user's environment raised or misfit: keep the run, then one line
            checkpoint = loop.save_checkpoint()
            run_dir.write_summary({"runner": "inline", "ended": "env_error", **loop.counters,
                                   "elapsed_s": loop.elapsed_s, "segment_s": loop.segment_s})
            print(f"error: {err}; the run is kept at episode {loop.counters['episodes']} ({checkpoint}); resume "
                  f"with: {resume_command(run_dir.path)}", file=sys.stderr)
            return 2
        stop.training_over()
        ended = stop.name or ("solved" if solved(loop.window, config.run) else
                              "plateau" if loop.learning_progress.plateaued else "budget")
        summary = {"runner": "inline", "ended": ended, **loop.counters, "elapsed_s": loop.elapsed_s,
                   "segment_s": loop.segment_s, "window": row.get("window", {})}
        run_dir.write_summary(summary)
        print(done_line(summary, config.run.stop_coverage))  # as the service's (cmcl.run_report)
        if stop.requested:
            print(f"stopped by {stop.name} at episode {loop.counters['episodes']}; checkpointed. Resume with: "
                  f"{resume_command(run_dir.path)}")
            return stop.exit_code
        if not request.no_eval:
            report_trained(config, run_dir)  # learning curve, held-out evaluation, misses, GIF
        print(f"run directory: {run_dir.path}")
    return 0


if __name__ == "__main__":
    exit_without_teardown(main())  # the exit status of sys.exit, without ~1-2 s of teardown

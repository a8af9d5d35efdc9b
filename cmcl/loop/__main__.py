"""Command line of the inline loop: `python -m cmcl.loop` trains (or resumes) one run and plots its learning curve.

Run:  python -m cmcl.loop --config configs/spread_cmcl.toml [--set run.episodes=40 --set run.dir=runs/smoke]
      python -m cmcl.loop --resume runs/smoke [--set run.episodes=80]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from cmcl.config import Config, ConfigError, load_config
from cmcl.io import codec
from cmcl.io.rundir import CHECKPOINT_GLOB, RunDirectory
from cmcl.io.runlock import RunDirectoryInUse, RunLock, holder_command
from cmcl.io.verified import CheckpointError
from cmcl.loop.inline import InlineLoop
from cmcl.progress import solved
from cmcl.stopping import StopSignals


def restore_newest_good(loop: InlineLoop, run_dir: RunDirectory) -> Path | None:
    """Restore the newest checkpoint that passes its checks (manifest digest, snapshot limits); each refused one
    is named on stderr and the one before it is tried. Returns the checkpoint restored, None if none passed."""
    for checkpoint in sorted(run_dir.checkpoints.glob(CHECKPOINT_GLOB), reverse=True):
        try:
            loop.restore(checkpoint)
            return checkpoint
        except (CheckpointError, codec.CodecError, OSError) as err:
            print(f"checkpoint refused: {err}", file=sys.stderr)
    return None


def main(argv: list[str] | None = None) -> int:
    """CLI entry point: train, or resume, one inline run; write the learning curve at the end. Exit codes: 0 done,
    2 bad config / arguments / run directory in use / nothing to resume, 130 / 143 stopped by SIGINT / SIGTERM
    (after a checkpoint)."""
    parser = argparse.ArgumentParser(prog="python -m cmcl.loop", description=__doc__.split("\n")[0])
    parser.add_argument("--config", help="TOML experiment file (default: built-in CMCL defaults)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="override one config value (repeatable)")
    parser.add_argument("--resume", metavar="DIR", help="continue the run in DIR from its latest checkpoint")
    parser.add_argument("--overwrite", action="store_true", help="start over in a run.dir that holds a run")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")
    args = parser.parse_args(argv)
    try:
        if args.resume:
            run_dir = RunDirectory.open(args.resume)
            config = run_dir.config(tuple(args.overrides))
            lock = RunLock.acquire(run_dir.path, holder_command())
        else:
            config = load_config(args.config, args.overrides)
            lock = RunLock.acquire(config.run.dir, holder_command())
            try:
                run_dir = RunDirectory.create(config.run.dir, config, overwrite=args.overwrite)
            except BaseException:
                lock.release()
                raise
    except (ConfigError, FileExistsError, FileNotFoundError, RunDirectoryInUse) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    with lock:
        return _train(args, config, run_dir)


def _train(args: argparse.Namespace, config: Config, run_dir: RunDirectory) -> int:
    """Build the loop, restore it when resuming, train until done or stopped; the run directory is locked."""
    loop = InlineLoop(config, run_dir, progress=None if args.quiet else print)
    if args.resume:
        if run_dir.runners() == {"service"}:
            print(f"error: {args.resume} was written by the service; resume it with "
                  f"python -m services.launch --resume {args.resume}", file=sys.stderr)
            return 2
        try:
            checkpoint = restore_newest_good(loop, run_dir)
        except ValueError as err:  # a checkpoint of other settings (shapes, folds): older ones are alike
            print(f"error: {args.resume} cannot resume under these settings: {err}", file=sys.stderr)
            return 2
        if checkpoint is None:
            print(f"error: {args.resume} holds no checkpoint to resume from that passes its checks", file=sys.stderr)
            return 2
        run_dir.truncate_rows_after(loop.counters["episodes"])
        print(f"resumed from {checkpoint} at episode {loop.counters['episodes']}")
    with StopSignals(notice=print) as stop:
        row = loop.run(stop=lambda: stop.requested)
        stop.training_over()
        ended = stop.name or ("solved" if solved(loop.window, config.run) else "budget")
        run_dir.write_summary({"runner": "inline", "ended": ended, **loop.counters, "elapsed_s": loop.elapsed_s,
                               "window": row.get("window", {})})
        if stop.requested:
            print(f"stopped by {stop.name} at episode {loop.counters['episodes']}; checkpointed. Resume with: "
                  f"python -m cmcl.loop --resume {run_dir.path}")
            return stop.exit_code
        from cmcl.io.plots import plot_learning_curves

        png = plot_learning_curves([run_dir.path], run_dir.path / "learning_curve.png",
                                   window=min(config.run.smoothing_window, max(1, config.run.episodes // 10)))
        print(f"run directory: {run_dir.path}  (learning curve: {png})")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""`python -m cmcl status DIR [DIR ...]`: where each run stands, in one line, read from its folder alone.

Nothing is written and nothing started (no Ray, no torch): the line comes from the run's config.toml (its runner's
budget), its newest progress row of metrics.jsonl (episodes, training seconds), its last 100 episode rows (coverage and
success), summary.json (how it ended) and its lock (who runs it now: `cmcl.run.runlock.holder_of`). For example

    runs/make-run | service | solved | 12,176 of 60,000 episodes | 130 s trained | last 100 episodes: cov 0.91,
        succ 0.60 | newest checkpoint learner-000003.pt
    runs/smoke | inline | stopped by SIGINT | 40 of 400 episodes | 3 s trained | last 40 episodes: cov 0.09, succ 0.00
        | newest checkpoint learner-000001.pt | resume: python -m cmcl resume runs/smoke

(each one line). A resumed run trains past its config.toml's run.episodes (`resume --more-episodes`): its episodes
are then shown alone.

A run whose lock is held is "running" (its holder named); one with neither a holder nor a summary newer than its
last row was cut off (a crash, SIGKILL: "cut off") and resumes from its newest checkpoint. Checkpoint files are
named, not decoded: `evaluate` and `resume` verify them.
"""

from __future__ import annotations

import contextlib
import json
import shlex
from collections import deque
from pathlib import Path
from typing import Any

from cmcl.config import ConfigError
from cmcl.io.metrics_log import MetricsError
from cmcl.io.resume_hint import python_command, resume_command
from cmcl.io.verified import VerifiedFile
from cmcl.run.flags import RUNNERS, RunRequestError
from cmcl.run.rundir import RunDirectory
from cmcl.run.runlock import holder_of

RECENT = 100  # episodes the coverage and success are averaged over (the `cov` of the progress line, MA 0.9's window)
ENDED = {"solved": "solved", "budget": "its budget done", "plateau": "stopped on a plateau",
         "SIGINT": "stopped by SIGINT", "SIGTERM": "stopped by SIGTERM", "diverged": "diverged",
         "env_error": "stopped by an error of its environment",
         "write_failure": "stopped: a file of the run could not be written (a full disk?)"}


def status_line(path: str | Path) -> str:
    """The one line of the run in `path` (see the module docstring); a folder that holds no run says so."""
    try:
        run_dir = RunDirectory.open(path)
        target = run_dir.config().run.episodes
        last = _last_progress(run_dir)
    except (FileNotFoundError, ConfigError, MetricsError) as err:
        return f"{path} | not a run it can read: {err}"
    summary, holder = run_dir.summary(), holder_of(run_dir.path)
    episodes = max(int(last.get("episodes", 0)), int(summary.get("episodes", 0)))
    elapsed = max(float(last.get("elapsed_s", 0.0)), float(summary.get("elapsed_s", 0.0)))
    try:
        runner = runner_of(run_dir)
    except ValueError:  # a start that failed before its first episode
        runner = "inline"
    if holder is not None:
        state = f"running ({holder})"
    elif summary and float(summary.get("elapsed_s", 0.0)) >= float(last.get("elapsed_s", 0.0)):
        state = ENDED.get(str(summary.get("ended")), str(summary.get("ended", "ended")))
    else:
        state = "cut off (no summary after its last row: a crash or SIGKILL)" if last else "not started"
    shown = f"{episodes:,} of {target:,} episodes" if episodes <= target else f"{episodes:,} episodes"
    parts = [str(path), runner, state, shown, f"{elapsed:.0f} s trained"]
    recent = last.get("recent", [])
    if recent:
        cov, succ = (sum(r.get(k, 0.0) for r in recent) / len(recent) for k in ("coverage", "success"))
        parts.append(f"last {len(recent)} episodes: cov {cov:.2f}, succ {succ:.2f}")
    newest = _newest_checkpoint(run_dir)
    parts.append(f"newest checkpoint {newest}" if newest else "no checkpoint yet")
    if holder is None and run_dir.stopped_before_a_checkpoint():  # nothing to resume: as its error line said
        parts.append(f"nothing to resume: make room, then start it again: {python_command()} -m cmcl train --config "
                     f"{shlex.quote(str(run_dir.config_path))}")
    elif holder is None and episodes < target and summary.get("ended") != "solved":
        parts.append(f"resume: {resume_command(run_dir.path)}")
    return " | ".join(parts)


def runner_of(run_dir: RunDirectory) -> str:
    """The runner that wrote `run_dir`: the one its summary.json names, else the one its last checkpoint of the
    supervisor's counters names (a run cut off before its summary), else the service if it holds a checkpoint
    (both runners write and resume the same checkpoints; one of the inline runner's own format of earlier versions is
    refused by cmcl.run.flags.open_run). Raises RunRequestError when none of these tells."""
    summary = run_dir.summary()
    if summary.get("runner") in RUNNERS:
        return summary["runner"]
    counters = run_dir.supervisor_counters  # a run cut off before its summary: its last checkpoint names it
    if counters.exists():
        with contextlib.suppress(ValueError, OSError):
            runner = json.loads(counters.read_text()).get("runner")
            if runner in RUNNERS:
                return runner
    if "inline" in run_dir.runners():
        return "inline"
    if run_dir.runners() or run_dir.service_dir.is_dir():
        return "service"
    if run_dir.never_trained():  # a start that failed before its first episode (e.g. of older code) left it
        config = shlex.quote(str(run_dir.config_path))
        raise RunRequestError(f"cannot tell which runner wrote {str(run_dir.path)!r}: it never trained (only the "
                              f"config of a start that failed); start it with {python_command()} -m cmcl train "
                              f"--config {config}, or pass --runner {' or --runner '.join(RUNNERS)}")
    raise RunRequestError(f"cannot tell which runner wrote {str(run_dir.path)!r} (no checkpoint, no summary.json); "
                          f"pass --runner {' or --runner '.join(RUNNERS)}")


def _last_progress(run_dir: RunDirectory) -> dict[str, Any]:
    """The newest row's episodes and training seconds, and the last RECENT episode rows that carry a coverage
    ("recent"); {} when there is no row."""
    last: dict[str, Any] = {}
    recent: deque[dict[str, Any]] = deque(maxlen=RECENT)
    for row in run_dir.rows():
        if row.get("kind") in ("episode", "progress"):
            last = {"episodes": row.get("episodes", 0), "elapsed_s": row.get("elapsed_s", 0.0)}
        if row.get("kind") == "episode" and "coverage" in row:
            recent.append(row)
    return {**last, "recent": list(recent)} if last else {}


def _newest_checkpoint(run_dir: RunDirectory) -> str | None:
    """The name of the newest policy checkpoint file (the learner's newest generation), not verified; None when there
    is none."""
    learner = VerifiedFile(run_dir.service_dir / "learner.pt")
    generations = learner.generations()
    return learner.file_of(generations[0]).name if generations else None


def status_command(paths: list[str]) -> int:
    """Print one line per run folder; exit 0, or 2 when a folder holds no run it can read."""
    lines = [status_line(path) for path in paths]
    print("\n".join(lines))
    return 2 if any(" | not a run it can read: " in line for line in lines) else 0

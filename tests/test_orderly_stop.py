"""A run stopped in order by a file it could not write, before its first checkpoint, as a new user meets it
(subprocesses; the file-size limit of `ulimit -f` stands in for a full disk): `status` calls it that stop, not a
crash, offers no resume of a run with nothing to resume, and the run starts again without --overwrite, as the
error line advised (cmcl.run.flags.record_write_failure, cmcl.run.rundir.RunDirectory.stopped_before_a_checkpoint)."""

from __future__ import annotations

import resource
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FILE_LIMIT = 48 * 1024  # bytes any one file may grow to (RLIMIT_FSIZE): metrics.jsonl outgrows it within seconds
TINY = ["env.num_envs=2", "maddpg.batch_size=16", "maddpg.warmup=32", "maddpg.hidden=16", "replay.capacity=600",
        "teams.agent.algorithm=maddpg"]


def limit_file_size() -> None:
    """In the child: no file larger than FILE_LIMIT (Python ignores SIGXFSZ, so a write past it fails with EFBIG)."""
    resource.setrlimit(resource.RLIMIT_FSIZE, (FILE_LIMIT, FILE_LIMIT))


def cmcl(*args: str, limited: bool = False) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cmcl", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=300, preexec_fn=limit_file_size if limited else None)


def train(run_dir: Path, episodes: int, limited: bool = False) -> subprocess.CompletedProcess:
    sets = [arg for text in (*TINY, f"run.episodes={episodes}", f"run.dir={run_dir}") for arg in ("--set", text)]
    return cmcl("train", "--runner", "inline", "--set", "env.factory=cmcl.envs.examples.reach:parallel_env", *sets,
                "--no-eval", limited=limited)


def test_a_write_failure_before_a_checkpoint_is_an_orderly_stop_that_resumes_from_its_replay(tmp_path):
    """Cut off by the file-size limit before the learner's first checkpoint: the stop is said and recorded (status: not
    a crash), and the resume it offers, from the replay the run kept, goes through once there is room."""
    run_dir = tmp_path / "run"
    stopped = train(run_dir, 100000, limited=True)
    assert stopped.returncode == 2, stopped.stdout + stopped.stderr
    assert "resume from its replay" in stopped.stderr or "its replay (no policy checkpoint yet)" in stopped.stderr, \
        stopped.stderr
    status = cmcl("status", str(run_dir)).stdout
    assert "stopped: a file of the run could not be written" in status and "cut off" not in status, status
    assert "| resume:" in status, status
    again = cmcl("resume", str(run_dir), "--set", "run.episodes=4", "--no-eval")
    assert again.returncode == 0, again.stderr

"""A resume's --set overrides and --more-episodes are recorded, as a new user meets them (subprocesses): one line per
changed key (old -> new), the run's config.toml rewritten, which a later plain resume, status, evaluate and
summary.json's provenance read; a refused resume changes nothing (cmcl.run.flags.record_resume_settings)."""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TINY = ["env.factory=cmcl.envs.examples.reach:parallel_env", "env.num_envs=2", "maddpg.warmup=32",
        "maddpg.batch_size=16", "maddpg.hidden=16", "replay.capacity=600"]


def cmcl(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cmcl", *args, "--no-eval"], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)


def actor_lr(run_dir: Path) -> float:
    return tomllib.loads((run_dir / "config.toml").read_text())["maddpg"]["actor_lr"]


def test_a_resumes_settings_are_recorded_and_kept_by_the_next_plain_resume(tmp_path):
    run_dir = tmp_path / "run"
    sets = [arg for text in (*TINY, "run.episodes=4", f"run.dir={run_dir}") for arg in ("--set", text)]
    assert cmcl("train", "--runner", "inline", *sets).returncode == 0
    before = (run_dir / "config.toml").read_bytes()
    refused = cmcl("resume", str(run_dir), "--set", "maddpg.hidden=8")  # other network shapes: refused
    assert refused.returncode == 2 and (run_dir / "config.toml").read_bytes() == before
    changed = cmcl("resume", str(run_dir), "--set", "maddpg.actor_lr=0.0005", "--more-episodes", "4")
    assert changed.returncode == 0, changed.stderr
    assert "resume sets maddpg.actor_lr: 0.001 -> 0.0005 (recorded in config.toml)" in changed.stdout
    assert "resume sets run.episodes: 4 -> 8" in changed.stdout
    assert actor_lr(run_dir) == 0.0005
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["episodes"] == 8
    plain = cmcl("resume", str(run_dir), "--more-episodes", "4")
    assert plain.returncode == 0 and "maddpg.actor_lr" not in plain.stdout, plain.stdout
    assert actor_lr(run_dir) == 0.0005
    status = subprocess.run([sys.executable, "-m", "cmcl", "status", str(run_dir)], cwd=ROOT, capture_output=True,
                            text=True, timeout=60).stdout
    assert "its budget done | 12 of 12 episodes" in status, status

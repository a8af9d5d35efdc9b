"""The rule a run trains with when none is named, as a new user meets it: MADDPG (uniform replay, which no rule here
has beaten, lab/RESULTS.md) on a user's env.factory and on the built-in tasks; and CMCL's early hint "cov may wait"
only on a run that has a coverage to wait for (subprocesses of `python -m cmcl train`, and the progress line)."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

from cmcl.config import load_config
from cmcl.progress.rows import progress_line

ROOT = Path(__file__).resolve().parents[1]
REACH = "env.factory=cmcl.envs.examples.reach:parallel_env"
TINY = ["env.num_envs=2", "maddpg.batch_size=16", "maddpg.warmup=32", "maddpg.hidden=16", "replay.capacity=600",
        "teachers.batch_size=16", "teachers.hidden=16", "teachers.num_folds=3", "icm.batch_size=16"]


def train(run_dir: Path, *overrides: str) -> str:
    """`python -m cmcl train --runner inline` with the tiny settings and `overrides`; its output."""
    sets = [arg for text in (*TINY, *overrides, f"run.dir={run_dir}") for arg in ("--set", text)]
    done = subprocess.run([sys.executable, "-m", "cmcl", "train", "--runner", "inline", *sets, "--no-eval"],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout + done.stderr


def test_a_users_env_without_a_rule_trains_maddpg(tmp_path):
    out = train(tmp_path / "run", REACH, "run.episodes=2")
    stored = tomllib.loads((tmp_path / "run" / "config.toml").read_text())
    assert stored["teams"]["agent"]["algorithm"] == "maddpg"
    assert "λ" not in out  # no rule of the run reads λ


def test_the_built_in_task_without_a_rule_is_maddpg():
    assert load_config(None, []).teams["agent"].algorithm == "maddpg"
    assert {team.algorithm for team in load_config(None, ["env.task='tag'"]).teams.values()} == {"maddpg"}


def test_cmcls_hint_waits_for_coverage_only_where_the_run_has_one(tmp_path):
    # λ's ramp spans 2,000 episodes: every line of the 3 s has λ < 0.5
    out = train(tmp_path / "run", REACH, "teams.agent.algorithm=cmcl", "run.episodes=2000", "run.max_seconds=3")
    lines = [line for line in out.splitlines() if line.startswith("ep ")]
    assert lines and all("KP excludes the hardest rows" in line for line in lines), out
    assert "cov may wait" not in out
    window = {"coverage": 0.4, "reward": {"agent": 1.0}}
    with_coverage = progress_line(10, 100, 300, 5, window, 0.1, {}, 3.0, notes=["normal while λ < 0.5: KP excludes "
                                                                                "the hardest rows, cov may wait"])
    assert with_coverage.endswith("KP excludes the hardest rows, cov may wait")

"""No run that trains nothing without a word (subprocesses of `python -m cmcl train`): a run that ends with 0 learner
updates says so in one line naming the warm-up and the env steps it took; a run.episodes that the batch of worlds
rounds up is said with the count played; the README's inline smoke command trains (cmcl.run.report,
cmcl.run.preflight)."""

from __future__ import annotations

import math
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from cmcl.config import load_config

ROOT = Path(__file__).resolve().parents[1]


def train(*args: str) -> str:
    done = subprocess.run([sys.executable, "-m", "cmcl", "train", "--runner", "inline", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout + done.stderr


def readme_smoke_command() -> list[str]:
    """The README's inline training command (its "train inline" row), as argv after `python -m cmcl train`."""
    row = next(line for line in (ROOT / "README.md").read_text().splitlines() if line.startswith("| train inline"))
    command = re.search(r"`python -m cmcl train ([^`]+)`", row).group(1)
    return shlex.split(command)


@pytest.mark.parametrize("no_eval", [True, False], ids=["no-eval", "with-eval"])
def test_a_run_without_an_update_says_so_naming_the_warmup(tmp_path, no_eval):
    out = train("--set", "env.num_envs=4", "--set", "maddpg.warmup=2000", "--set", "run.episodes=10", "--set",
                "maddpg.hidden=16", "--set", f"run.dir={tmp_path / 'run'}", *(["--no-eval"] if no_eval else []))
    notes = [line for line in out.splitlines() if line.startswith("note: no learner update")]
    assert len(notes) == 1, out
    assert "maddpg.warmup = 2000 transitions" in notes[0] and "the run took 360 env steps (12 episodes)" in notes[0]
    assert ("note: run.episodes = 10 is not a multiple of env.num_envs = 4, the worlds played at once: it ends after "
            "12 episodes") in out
    if not no_eval:  # said before the evaluation of the untrained policy
        assert out.index("note: no learner update") < out.index("held-out evaluation")


def test_the_readme_smoke_command_reaches_its_warmup():
    args = readme_smoke_command()
    config = load_config(args[args.index("--config") + 1], [args[i + 1] for i, a in enumerate(args) if a == "--set"])
    worlds = config.env.num_envs
    transitions = math.ceil(config.run.episodes / worlds) * worlds * config.env.episode_length
    assert transitions >= config.maddpg.warmup + 10 * config.maddpg.update_every, (transitions, config.maddpg)
    assert config.run.episodes % worlds == 0  # nothing rounded


def test_the_readme_smoke_command_trains(tmp_path):
    args = [a if not a.startswith("run.dir=") else f"run.dir={tmp_path / 'smoke'}" for a in readme_smoke_command()]
    out = train(*args, "--no-eval")
    done = next(line for line in out.splitlines() if line.startswith("done: "))
    assert int(re.search(r"(\d+) updates", done).group(1)) > 0 and "note: " not in out, out

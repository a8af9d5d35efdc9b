"""Numbers that were silently wrong on your own environment (issue 37 items 6-8, 11), each on a real PettingZoo env:
success and coverage when agents leave early, observations that do not fit their declared space, λ's schedule on
episodes shorter than env.episode_length, and an AEC env given as the factory. tests/probe_env.py is the probe."""

import subprocess
import sys
from pathlib import Path

import pytest

from cmcl.envs.factory import EnvFactoryError, load_factory

ROOT = Path(__file__).resolve().parents[1]


# ----- item 11: an AEC environment -----------------------------------------------------------------------------------
def test_an_aec_environment_is_named_with_the_parallel_env_to_use():
    with pytest.raises(EnvFactoryError, match=r"returned an AEC environment \(OrderEnforcingWrapper\), which steps "
                                              r"one agent at a time; .* use 'mpe2.simple_spread_v3:parallel_env'"):
        load_factory("mpe2.simple_spread_v3:env")()


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "cmcl", "train", "--runner", "inline", "--no-eval", "--quiet",
                           *args], cwd=ROOT, capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("sets, says", [
    (["env.factory=mpe2.simple_spread_v3:env"], "returned an AEC environment"),
])
def test_the_command_line_says_what_does_not_fit_in_one_line_and_exits_2(sets, says, tmp_path):
    args = [a for s in [*sets, "run.episodes=2", f"run.dir={tmp_path / 'run'}"] for a in ("--set", s)]
    done = run_cli(*args)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: env.factory") and says in lines[0], done.stderr

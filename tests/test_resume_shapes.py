"""A resume whose --set changes what the run's checkpoints hold is refused before anything starts, in one line naming
the key (cmcl.run.resume_shapes). Before (found by hand 2026-12-06): `resume DIR --set env.num_agents=3` ended the
inline runner in "alpha in state must be a scalar or have one entry per agent (3), got 4" and the service in a
traceback from its replay server's start."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from cmcl.config import ConfigError
from cmcl.run.resume_shapes import check_resume_shapes
from tests.in_process import trained_inline_run
from tests.tiny import make_tiny_config

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize(("section", "key", "value", "named"), [
    ("env", "num_agents", 3, "(agents: 4 in them, 3 with these settings)"),
    ("maddpg", "hidden", 16, "maddpg actor.layers.0.weight: (4, 18, 32) in them, (4, 18, 16) with these settings"),
    ("teachers", "num_folds", 4, "teachers.num_folds: 5 in them, 4 with these settings"),
])
def test_a_setting_that_changes_the_checkpoints_shapes_is_named(section, key, value, named):
    stored = make_tiny_config("cmcl")
    resumed = make_tiny_config("cmcl", sections={section: {key: value}})
    with pytest.raises(ConfigError) as refused:
        check_resume_shapes(stored, resumed, (f"{section}.{key}={value}", "service.metrics_port=0"))
    assert str(refused.value).startswith(f"resume --set {section}.{key}={value}: the run's checkpoints hold other "
                                         "shapes"), refused.value  # the unchanged override is not named
    assert named in str(refused.value), refused.value


def test_a_setting_that_keeps_the_shapes_passes():
    stored = make_tiny_config("cmcl")
    check_resume_shapes(stored, make_tiny_config("cmcl", sections={"maddpg": {"actor_lr": 5e-4}}),
                        ("maddpg.actor_lr=0.0005",))


@pytest.mark.parametrize("runner", ["inline", "service"])
def test_the_resume_is_refused_in_one_line_before_anything_starts(runner, tmp_path):
    path = tmp_path / "run"
    trained_inline_run(make_tiny_config("cmcl", dir=str(path), episodes=8))  # either runner resumes it: the
    # service's resume reaches the same check, before Ray
    before = {p: p.read_bytes() for p in path.rglob("*") if p.is_file() and p.name != "run.lock"}
    done = subprocess.run([sys.executable, "-m", "cmcl", "resume", str(path), "--runner", runner, "--set",
                           "env.num_agents=3", "--more-episodes", "4", "--quiet", "--no-eval",
                           *(["--metrics-port", "0"] if runner == "service" else [])],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stdout + done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: resume --set env.num_agents=3"), done.stderr
    assert "the run's checkpoints hold other shapes (agents: 4 in them, 3 with these settings)" in lines[0]
    assert {p: p.read_bytes() for p in path.rglob("*") if p.is_file() and p.name != "run.lock"} == before

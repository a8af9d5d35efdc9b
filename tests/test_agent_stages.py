"""python -m cmcl stages (cmcl/run/agent_stages.py): the plan of an agent-count curriculum, what is refused before any
stage trains, and how a rerun goes on from a stopped stage."""

from __future__ import annotations

from pathlib import Path

import pytest

from cmcl.__main__ import main
from cmcl.config import ConfigError
from cmcl.run.agent_stages import plan_stages, stage_finished, stage_request
from cmcl.run.flags import RunRequest
from cmcl.run.rundir import RunDirectory


def test_the_plan_chains_each_stage_to_the_one_before(tiny_config, tmp_path):
    config = tiny_config("maddpg", dir=str(tmp_path / "cur"))
    stages = plan_stages(config, [2, 4, 8], [100, 200, 300])
    assert [s.num_agents for s in stages] == [2, 4, 8]
    assert [s.run_dir.name for s in stages] == ["n2", "n4", "n8"]
    assert "run.init_from" not in " ".join(stages[0].overrides)
    assert f"run.init_from={tmp_path / 'cur' / 'n2'}" in stages[1].overrides
    assert "run.episodes=300" in stages[2].overrides and "run.stop_progress=0.0" in stages[2].overrides
    assert [s.last for s in stages] == [False, False, True]


@pytest.mark.parametrize(("agents", "episodes", "message"), [
    ([4, 2], None, "increasing order"), ([2, 2], None, "increasing order"), ([0, 2], None, "agent counts >= 1"),
    ([2, 4], [100], "one budget per stage"), ([2, 4], [100, 0], "must be >= 1")])
def test_a_bad_plan_names_the_flag_and_the_value(tiny_config, agents, episodes, message):
    with pytest.raises(ConfigError, match=message):
        plan_stages(tiny_config("maddpg"), agents, episodes)


def test_networks_that_grow_with_the_agent_count_are_refused_before_anything_trains(tmp_path, tiny_config_file,
                                                                                      capsys):
    config = str(tiny_config_file("maddpg", dir=str(tmp_path / "cur")))
    for extra in ([], ["--set", "maddpg.networks=shared"]):
        assert main(["stages", "--runner", "inline", "--agents", "2", "3", "--config", config, *extra]) == 2
        err = capsys.readouterr().err
        assert "shapes do not depend on the number of agents" in err and "at N = 2" in err and "at N = 3" in err
    assert not (tmp_path / "cur").exists()


def test_a_rerun_keeps_finished_stages_and_resumes_a_stopped_one(tmp_path, tiny_config):
    """A stage folder with a finished summary is kept, one with a checkpoint is resumed, one without starts over."""
    from services.launch import train_in_process

    config = tiny_config("maddpg", dir=str(tmp_path / "cur"), episodes=4)
    stages = plan_stages(config, [2, 3], None)
    base = RunRequest(runner="inline", overrides=("run.seed=3",))
    fresh = stage_request(base, stages[0])
    assert fresh.resume_dir is None and fresh.overwrite and fresh.no_eval  # not the last stage: no evaluation
    assert fresh.overrides[0] == "run.seed=3" and "env.num_agents=2" in fresh.overrides
    staged = tiny_config("maddpg", dir=str(stages[0].run_dir), episodes=4)
    run_dir = RunDirectory.create(staged.run.dir, staged)
    train_in_process(staged, run_dir)  # the inline runner: leaves the service's checkpoints
    resumed = stage_request(base, stages[0])
    assert resumed.resume_dir == str(stages[0].run_dir) and resumed.overrides == ()
    assert not stage_finished(stages[0])
    run_dir.write_summary({"ended": "SIGINT"})
    assert not stage_finished(stages[0])
    run_dir.write_summary({"ended": "plateau"})
    assert stage_finished(stages[0]) and not stage_request(base, stages[1]).no_eval
    assert not Path(stages[1].run_dir).exists()


def test_entity_networks_carry_from_two_agents_to_three_and_a_rerun_keeps_the_stages(tmp_path, tiny_config_file,
                                                                                     capsys):
    """The whole command, inline: stage N = 2 trains, N = 3 starts from its networks (the same parameters, now
    acting for 3 agents), and the same command afterwards trains nothing again."""
    import torch

    root = tmp_path / "cur"
    argv = ["stages", "--runner", "inline", "--agents", "2", "3", "--stage-episodes", "8", "8", "--no-eval",
            "--config", str(tiny_config_file("maddpg", dir=str(root))), "--set", "maddpg.networks=entity"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert f"actors and critics initialised from {root / 'n2' / 'checkpoints'}" in out
    assert "stage N = 3 ended (budget) at episode 8" in out
    first, second = (RunDirectory.open(root / f"n{n}") for n in (2, 3))
    assert first.config().env.spread.num_agents == 2 and second.config().env.spread.num_agents == 3
    assert second.config().run.init_from == str(root / "n2")
    a, b = (d.newest_policy().state["maddpg"]["actor"] for d in (first, second))
    assert a.keys() == b.keys() and all(a[k].shape == b[k].shape for k in a)
    assert any(not torch.equal(a[k], b[k]) for k in a), "the second stage trained on from the first's weights"
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "stage N = 2: done earlier" in out and "stage N = 3: done earlier" in out


@pytest.mark.slow
def test_the_readme_stages_command_runs_on_the_service(tmp_path):
    """The README's command as a user types it (the service runner, its own embedded Ray per stage), at a tiny
    budget: both stages end, the second starts from the first's learner checkpoint and ends with the evaluation."""
    import subprocess
    import sys

    from tests.tiny import tiny_overrides

    sets = [a for s in (*tiny_overrides(service=True), f"run.dir={tmp_path / 'cur'}", "maddpg.networks=entity")
            for a in ("--set", s)]
    done = subprocess.run([sys.executable, "-m", "cmcl", "stages", "--agents", "2", "3", "--stage-episodes", "8",
                           "8", "--config", "configs/spread_maddpg.toml", "--num-cpus", "2", *sets],
                          capture_output=True, text=True, timeout=600, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "actors and critics initialised from" in done.stdout and "learner-" in done.stdout
    assert "held-out evaluation" in done.stdout and "stage N = 3 ended (budget)" in done.stdout


def test_a_stage_ends_when_its_coverage_stops_progressing(tmp_path, tiny_config_file):
    """run.stop_progress with the default signal, the change of the training coverage: with an enormous
    threshold the first stage ends after patience + 1 windows of episodes, far before its budget; the last stage, the
    target task, trains its whole budget."""
    root = tmp_path / "cur"
    argv = ["stages", "--runner", "inline", "--agents", "2", "3", "--stage-episodes", "400", "8", "--no-eval",
            "--quiet", "--config", str(tiny_config_file("maddpg", dir=str(root))), "--set", "maddpg.networks=entity",
            "--set", "run.stop_progress=1e9", "--set", "run.progress_window=4", "--set", "run.progress_patience=2"]
    assert main(argv) == 0
    first, last = (RunDirectory.open(root / n).summary() for n in ("n2", "n3"))
    assert first["ended"] == "plateau" and first["episodes"] < 40, first
    assert last["ended"] == "budget" and last["episodes"] >= 8, last

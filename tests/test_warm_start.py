"""run.init_from: a new run's actors and critics start from another run's newest policy (cmcl.run.warm_start),
on the command line (the inline runner: the service's roles in one process) and in the learner itself; bad sources
are refused before the new run's directory exists, naming the field and the value."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from cmcl.__main__ import main as cmcl
from cmcl.run.rundir import RunDirectory
from cmcl.run.warm_start import WARM_PARTS

NO_UPDATES = ["--set", "maddpg.warmup=600"]  # 4 episodes fill 120 rows, fewer than the warm-up: no update, weights stay


def main(argv: list[str]) -> int:
    """`python -m cmcl train --runner inline ARGV`."""
    return cmcl(["train", "--runner", "inline", *argv])


def _policy(run: Path) -> dict:
    return RunDirectory.open(run).newest_policy().state["maddpg"]


@pytest.fixture
def source_run(tmp_path, tiny_config_file) -> Path:
    """A finished tiny MADDPG run (8 episodes, several updates): the source of the warm starts."""
    run = tmp_path / "source"
    assert main(["--config", str(tiny_config_file("maddpg", dir=str(run), episodes=8)), "--no-eval", "--quiet"]) == 0
    return run


def test_a_warm_started_run_begins_with_the_source_networks_and_fresh_optimisers(tmp_path, source_run,
                                                                                   tiny_config_file, capsys):
    config = str(tiny_config_file("maddpg", dir=str(tmp_path / "warm"), episodes=4))
    assert main(["--config", config, "--no-eval", "--set", f"run.init_from={source_run}", *NO_UPDATES]) == 0
    assert "actors and critics initialised from" in capsys.readouterr().out
    source, warm = _policy(source_run), _policy(tmp_path / "warm")
    for part in WARM_PARTS:
        for key, tensor in source[part].items():
            torch.testing.assert_close(warm[part][key], tensor, rtol=0, atol=0)
    assert warm["updates"] == 0 and not warm["actor_opt"]["state"]  # optimisers and counters start afresh
    cold = tmp_path / "cold"  # the same run without init_from starts elsewhere: the comparison above can fail
    assert main(["--config", config, "--no-eval", "--quiet", "--set", f"run.dir={cold}", *NO_UPDATES]) == 0
    assert not torch.equal(_policy(cold)["actor"]["layers.0.weight"], source["actor"]["layers.0.weight"])


def test_the_service_learner_warm_starts_a_fresh_run_only(tmp_path, source_run, tiny_config):
    """The learner actor's class, constructed in-process: fresh, it loads the source; restoring its own checkpoint,
    the checkpoint wins."""
    from services.roles.learner import Learner

    config = tiny_config("maddpg", service=True, dir=str(tmp_path / "svc"), init_from=str(source_run))
    learner = Learner(config, seed=3, checkpoint_path=str(tmp_path / "learner.pt"))
    source = _policy(source_run)
    torch.testing.assert_close(learner.maddpg.critic.state_dict()["layers.1.weight"],
                               source["critic"]["layers.1.weight"], rtol=0, atol=0)
    with torch.no_grad():
        learner.maddpg.critic.layers[1].weight.add_(1.0)
    learner.save()
    restarted = Learner(config, seed=3, checkpoint_path=str(tmp_path / "learner.pt"))
    assert restarted.resumed
    torch.testing.assert_close(restarted.maddpg.critic.layers[1].weight, learner.maddpg.critic.layers[1].weight)


@pytest.mark.parametrize("case", ["no_run", "no_policy", "other_agents"])
def test_a_bad_source_is_refused_before_the_new_run_exists(tmp_path, source_run, tiny_config_file, capsys, case):
    if case == "no_run":
        source, sets = tmp_path / "nope", []
    elif case == "no_policy":
        source, sets = source_run, []
        for checkpoint in RunDirectory.open(source_run).service_dir.glob("learner*"):  # the policy's files
            checkpoint.unlink()
    else:
        source, sets = source_run, ["--set", "env.num_agents=3"]
    new = tmp_path / "new"
    config = str(tiny_config_file("maddpg", dir=str(new), episodes=4))
    assert main(["--config", config, "--set", f"run.init_from={source}", *sets]) == 2
    err = capsys.readouterr().err
    assert f"run.init_from={str(source)!r}" in err and "Traceback" not in err
    assert {"no_run": "no run directory there", "no_policy": "holds no policy checkpoint",
            "other_agents": "has shape ("}[case] in err
    assert not new.exists()

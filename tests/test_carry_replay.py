"""run.carry_replay: a stage of the agent-count curriculum starts with the replay rows of the stage before (the inline
runner, and the replay server itself), and what is refused, naming the field."""

from __future__ import annotations

import numpy as np
import pytest

from cmcl.__main__ import main
from cmcl.config import ConfigError, load_config
from cmcl.io.durable import ReplayStore
from cmcl.run.rundir import RunDirectory


def newest_storage(run_dir):
    """The replay rows of the run's last checkpoint (the replay server's snapshot, either runner)."""
    return ReplayStore(RunDirectory.open(run_dir).service_replay_dir).read_snapshot()["replay"]["storage"]


@pytest.mark.parametrize("tags", [False, True])
def test_a_stages_run_two_to_four_starts_the_second_stage_with_the_first_stages_rows(tmp_path, tiny_config_file,
                                                                                     capsys, tags):
    root = tmp_path / "cur"
    config = str(tiny_config_file("maddpg", dir=str(root)))
    argv = ["stages", "--runner", "inline", "--agents", "2", "4", "--stage-episodes", "8", "8", "--no-eval",
            "--config", config, "--set", "maddpg.networks=entity", "--set", "run.carry_replay=true",
            "--set", f"env.agent_tags={str(tags).lower()}"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    first = newest_storage(root / "n2")
    assert first["n_agents"] == 2 and first["size"] > 0 and "present" not in first  # the first stage: its own rows
    assert f"replay: starts with the rows of {root / 'n2'}" in out
    assert not RunDirectory.open(root / "n2").config().run.carry_replay  # nothing before the first stage
    second = newest_storage(root / "n4")
    assert second["n_agents"] == 4 and second["size"] > first["size"]  # the capacity (600) holds both stages' rows
    carried = first["size"]
    present = second["present"]
    np.testing.assert_array_equal(present[:carried], [[True, True, False, False]] * carried)  # oldest: stage 1's
    assert present[carried:].all()  # then stage 2's own rows, all four agents
    order = np.argsort(first["id"])
    np.testing.assert_array_equal(second["act"][:carried, :2], first["act"][order])
    np.testing.assert_array_equal(second["obs"][:carried, :2, :8], first["obs"][order][:, :, :8])
    assert not second["obs"][:carried, 2:].any() and not second["rew"][:carried, 2:].any()
    if tags:  # the own tag (column 10 of 2 agents' rows, 18 of 4 agents') and the other agent's (11 -> 19) carried
        np.testing.assert_array_equal(second["obs"][:carried, :2, 18:20], first["obs"][order][:, :, 10:12])
    capsys.readouterr()  # rows are carried between runs with the same env.agent_tags only
    assert main(["train", "--runner", "inline", "--config", config, "--set", "maddpg.networks=entity",
                 "--set", "run.carry_replay=true", "--set", f"run.init_from={root / 'n2'}",
                 "--set", f"run.dir={tmp_path / 'other'}", "--set", f"env.agent_tags={str(not tags).lower()}"]) == 2
    assert "env.agent_tags" in capsys.readouterr().err and not (tmp_path / "other").exists()


@pytest.mark.parametrize(("overrides", "message"), [
    (("maddpg.networks='per_agent'", "teams.agent.algorithm='maddpg'"), "maddpg.networks = 'entity'"),
    (("maddpg.networks='entity'", "teams.agent.algorithm='cmcl'"),
     r"every team's rule to mask absent agents, one of \['maddpg', 'per'\]")])
def test_carry_replay_without_entity_networks_or_with_scoring_teachers_is_refused(overrides, message):
    with pytest.raises(ConfigError, match=f"run.carry_replay needs {message}.*got True"):
        load_config(None, ("run.carry_replay=true", *overrides))


def test_carry_replay_outside_navigation_is_refused():
    with pytest.raises(ConfigError, match="run.carry_replay needs env.task = 'spread'.*got True"):
        load_config("configs/tag_maddpg.toml", ("run.carry_replay=true", "maddpg.networks='entity'"))


def test_carry_replay_without_a_stage_before_or_from_a_run_without_rows_is_refused(tmp_path, tiny_config_file,
                                                                                  capsys):
    config = str(tiny_config_file("maddpg", dir=str(tmp_path / "run")))
    sets = ["--set", "maddpg.networks=entity", "--set", "run.carry_replay=true"]
    assert main(["train", "--runner", "inline", "--config", config, *sets]) == 2
    assert "run.carry_replay=True needs run.init_from" in capsys.readouterr().err
    assert main(["train", "--runner", "inline", "--config", config, *sets,
                 "--set", f"run.init_from={tmp_path / 'nothing'}"]) == 2
    assert "run.init_from" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def test_the_service_replay_server_starts_with_the_rows_of_the_run_before_and_restores_them_once(tmp_path,
                                                                                                 tiny_config):
    """The service runner's side, in-process: a new replay server carries the rows of the run before from its replay
    store, snapshots them (a restart restores them, it does not carry them twice), and the learner trains on them."""
    from services.roles.learner import Learner
    from services.roles.replay_server import ReplayServer
    from tests.test_agent_padding import small_rows

    def config(n, **run):
        return tiny_config("maddpg", service=True, sections={"maddpg": {"networks": "entity"},
                                                             "env": {"num_agents": n}}, **run)

    small = config(2, dir=str(tmp_path / "n2"))
    source = ReplayServer(small.to_dict(), str(RunDirectory.create(small.run.dir, small).service_replay_dir))
    rows = small_rows(m=120)  # over the tiny warm-up (96), so that it samples
    source.replay.add(rows["obs"], rows["act"], rows["rew"], rows["next_obs"], rows["done"], np.arange(120) // 30)
    source.snapshot()
    big = config(4, dir=str(tmp_path / "n4"), init_from=small.run.dir, carry_replay=True)
    store = str(RunDirectory.create(big.run.dir, big).service_replay_dir)
    server = ReplayServer(big.to_dict(), store)
    assert not server.resumed and server.replay.size == 120 and server.replay.storage.absent_rows == 120
    np.testing.assert_array_equal(server.replay.storage.act[:120, :2], rows["act"])
    again = ReplayServer(big.to_dict(), store)
    assert again.resumed and again.replay.size == 120 and again.replay.storage.absent_rows == 120
    from cmcl.replay.buffer_steps import sample_owner_batches

    batch = sample_owner_batches(server.replay, 2, 8, [np.random.default_rng(i) for i in range(4)], [0.0] * 4)
    assert batch.minibatch(0, False)["present"][:, :, 2:].sum() == 0
    learner = Learner(config(4).to_dict(), 0)  # its own warm start is another test's: only the update here
    feedback, _ = learner.update(batch)
    assert np.isfinite(feedback.td_abs).all() and (feedback.td_abs[:, 2:] == 0).all()  # agents 2, 3: never present


@pytest.mark.slow
def test_the_stages_command_carries_the_rows_on_the_service(tmp_path):
    """`python -m cmcl stages --set run.carry_replay=true` on the service runner (its own embedded Ray per stage), at
    a tiny budget: the second stage's replay server starts with the first stage's rows."""
    import subprocess
    import sys

    from tests.tiny import tiny_overrides

    sets = [a for s in (*tiny_overrides(service=True), f"run.dir={tmp_path / 'cur'}", "maddpg.networks=entity",
                        "run.carry_replay=true") for a in ("--set", s)]
    done = subprocess.run([sys.executable, "-m", "cmcl", "stages", "--agents", "2", "3", "--stage-episodes", "8",
                           "8", "--config", "configs/spread_maddpg.toml", "--num-cpus", "2", "--no-eval", *sets],
                          capture_output=True, text=True, timeout=600, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    assert f"replay: starts with the rows of {tmp_path / 'cur' / 'n2'}" in done.stdout
    from cmcl.io.durable import ReplayStore

    first, second = (ReplayStore(RunDirectory.open(tmp_path / "cur" / f"n{n}").service_replay_dir).read_snapshot()
                     ["replay"]["storage"] for n in (2, 3))
    carried = first["size"]
    assert carried > 0 and second["n_agents"] == 3
    assert (second["present"][:carried] == [True, True, False]).all() and second["present"][carried:].all()

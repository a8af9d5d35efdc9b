"""maddpg.entity_nearest: the entity actor and critic read only the k nearest entities of each kind.

The setting loads, reaches entity teachers and an entity ICM too, is refused in one line where it cannot apply,
reaches the learner of either runner and the rollout workers' numpy actor, trains inline, and its checkpoints say k,
so that evaluation rebuilds the same model and a resume or an evaluation under another k is refused; a warm start
(run.init_from) may change k, as it may change the agent count. The numpy actor's parity with the learner's, nearest
k included, is tests/test_policy.py.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from cmcl.config import ConfigError, load_config
from cmcl.config.runners import check_runner_keys
from tests.evaluation_output import evaluation_json

ROOT = Path(__file__).resolve().parents[1]
N8 = "configs/spread_n8.toml"
NEAREST = "maddpg.entity_nearest=3"


def test_the_default_reads_every_entity_and_the_setting_reaches_the_learner_of_either_runner():
    from cmcl.system import build_maddpg, layout_of

    default = load_config(N8)
    assert default.maddpg.entity_nearest == 0 and build_maddpg(default, layout_of(default), seed=0).actor.nearest == 0
    config = load_config(N8, [NEAREST])
    for runner in ("inline", "service"):  # both runners build the learner with cmcl.system.build_maddpg
        check_runner_keys(config, runner, overrides=[NEAREST])
    maddpg = build_maddpg(config, layout_of(config), seed=0)
    assert maddpg.entity_nearest == 3 and maddpg.actor.nearest == 3 and maddpg.critic.nearest == 3
    assert maddpg.target_actor.nearest == 3 and maddpg.target_critic.nearest == 3
    assert maddpg.state_dict()["entity_nearest"] == 3


def test_the_rollout_workers_numpy_actor_reads_the_same_entities():
    from cmcl.learners.weights import published_weights
    from cmcl.system import build_maddpg
    from services.roles.rollout import RolloutWorker

    worker = RolloutWorker(load_config(N8, [NEAREST, "env.num_envs=2"]).to_dict(), worker_id=0, seed=1)
    actor = published_weights(build_maddpg(worker.config, worker.layout, seed=0))["actor"]
    assert worker._numpy_policy(actor).nearest == 3


@pytest.mark.parametrize(("path", "sets", "message"), [
    ("configs/spread_maddpg.toml", [NEAREST],
     "maddpg.entity_nearest > 0 needs maddpg.networks = 'entity' (maddpg.networks = 'per_agent' here), got 3"),
    (N8, ["maddpg.networks='shared'", NEAREST],
     "maddpg.entity_nearest > 0 needs maddpg.networks = 'entity' (maddpg.networks = 'shared' here), got 3"),
    (N8, ["maddpg.entity_nearest=-1"], "maddpg.entity_nearest must be >= 0, got -1"),
    (N8, [NEAREST, "maddpg.assignment_loss=0.5"],
     "maddpg.assignment_loss > 0 needs every entity slot, maddpg.entity_nearest = 0 (its attention is over the "
     "picked ones, reordered per row) (maddpg.entity_nearest = 3 here), got 0.5"),
])
def test_the_config_refuses_what_cannot_apply_in_one_line_naming_the_field_and_value(path, sets, message):
    with pytest.raises(ConfigError) as err:
        load_config(path, sets)
    assert str(err.value) == message


def train_per_agent_with(setting: str, tmp_path) -> tuple[int, list[str]]:
    """`python -m cmcl train` of the per-agent navigation config with `setting` set, into tmp_path/run: (exit code,
    the lines of its stderr)."""
    done = subprocess.run([sys.executable, "-m", "cmcl", "train", "--runner", "inline", "--config",
                           "configs/spread_maddpg.toml", "--set", setting, "--set", f"run.dir={tmp_path / 'run'}",
                           "--quiet", "--no-eval"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    return done.returncode, done.stderr.strip().splitlines()


def test_the_command_line_refuses_it_for_other_networks_with_exit_2(tmp_path):
    code, lines = train_per_agent_with(NEAREST, tmp_path)
    assert code == 2 and len(lines) == 1 and "maddpg.entity_nearest > 0 needs" in lines[0], lines
    assert lines[0].endswith("got 3") and not (tmp_path / "run").exists()


def test_it_trains_inline_and_evaluation_and_warm_starts_rebuild_the_same_model(tmp_path, capsys):
    from cmcl.run.evaluate import load_policy
    from cmcl.run.evaluate import main as evaluate
    from cmcl.run.flags import check_warm_start
    from cmcl.run.rundir import RunDirectory
    from services.launch import train_in_process

    # two rounds of the 16 worlds, two updates in the second (tests/test_scale_presets.py's smoke, k = 3)
    run = tmp_path / "run"
    config = load_config(N8, [NEAREST, f"run.dir={run}", "run.init_from=", "run.episodes=32", "maddpg.warmup=480",
                              "maddpg.update_every=240", "run.max_seconds=0"])
    _, roles = train_in_process(config, RunDirectory.create(run, config))  # the inline runner
    maddpg = roles.learner.maddpg
    assert maddpg.updates > 0 and maddpg.actor.nearest == 3
    policy = RunDirectory.open(run).newest_policy()
    assert policy.state["maddpg"]["entity_nearest"] == 3
    assert "entity_nearest = 3" in (run / "config.toml").read_text()

    capsys.readouterr()
    assert evaluate([str(run), "--episodes", "4", "--no-gif"]) == 0  # the run's config.toml rebuilds k = 3
    assert evaluation_json(capsys.readouterr().out)["policy"] == "trained"
    assert load_policy(config, policy).actor.nearest == 3
    with pytest.raises(ValueError, match="trained with maddpg.entity_nearest = 3 and this config has 0"):
        load_policy(load_config(N8), policy)

    check_warm_start(load_config(N8, [NEAREST, f"run.init_from={run}"]))  # the same k: accepted
    check_warm_start(load_config(N8, [f"run.init_from={run}"]))  # another k: a transfer, as across agent counts
    with pytest.raises(ConfigError, match="run.init_from"):  # the shapes are still checked
        check_warm_start(load_config(N8, [f"run.init_from={run}", "maddpg.hidden=32"]))


def test_entity_teachers_and_an_entity_icm_read_the_learners_k():
    from cmcl.system import build_icm, build_teachers, layout_of

    sets = [NEAREST, "teams.agent.algorithm='cmcl'", "teachers.networks='entity'", "icm.networks='entity'"]
    config = load_config(N8, sets)
    layout = layout_of(config)
    assert build_teachers(config, layout, seed=0).net.nearest == 3
    assert build_icm(config, layout, seed=0).phi.nearest == 3
    every = load_config(N8, sets[1:])
    assert build_teachers(every, layout_of(every), seed=0).net.nearest == 0


def _far_landmark_moved(obs, num_agents: int):
    """obs float32[..., N, obs_dim] of navigation (landmark l at columns 4 + 2l, 5 + 2l, relative to the agent)
    -> a copy with each agent's farthest landmark moved twice as far away (still its farthest)."""
    import torch

    cols = 4 + torch.arange(num_agents) * 2
    rel = obs[..., torch.stack([cols, cols + 1], -1)]  # [..., N, L, 2]
    far = rel.square().sum(-1).argmax(-1, keepdim=True)  # [..., N, 1]
    moved = obs.clone()
    for dim in (0, 1):
        column = cols.expand(*far.shape[:-1], num_agents).gather(-1, far) + dim  # [..., N, 1]
        moved.scatter_(-1, column, 2 * obs.gather(-1, column))
    return moved


@pytest.mark.parametrize("nearest", [0, 2])
def test_with_k_the_teachers_and_the_icm_ignore_an_entity_beyond_it_and_without_k_they_do_not(nearest):
    import numpy as np
    import torch

    from cmcl.envs.entities import spread_layout
    from cmcl.scorers.icm import ICM
    from cmcl.scorers.teachers import TeacherEnsemble

    n, act_dim, rows = 4, 2, 16
    layout = spread_layout(n)
    gen = torch.Generator().manual_seed(0)
    obs = torch.randn(rows, n, layout.obs_dim, generator=gen)
    act = torch.rand(rows, n, act_dim, generator=gen) * 2 - 1
    moved = _far_landmark_moved(obs, n)
    joint = lambda o: torch.cat([o.flatten(1), act.flatten(1)], 1).numpy()  # noqa: E731 (nets.joint_input's order)
    teachers = TeacherEnsemble(n, in_dim=n * (layout.obs_dim + act_dim), num_folds=3, hidden=16, seed=1,
                               networks="entity", entity_layout=layout, act_dim=act_dim, entity_nearest=nearest)
    icm = ICM(n, layout.obs_dim, act_dim, feature_dim=8, hidden=16, seed=1, networks="entity", agents=list(range(n)),
              entity_layout=layout, entity_nearest=nearest)
    q, q_moved = teachers.predict(joint(obs)), teachers.predict(joint(moved))  # [A, M, K]
    phi, phi_moved = (icm.phi(o.transpose(0, 1)).detach().numpy() for o in (obs, moved))  # [A, M, feature]
    if nearest:
        np.testing.assert_allclose(q_moved, q, rtol=0, atol=1e-6)
        np.testing.assert_allclose(phi_moved, phi, rtol=0, atol=1e-6)
    else:  # every entity read: the moved landmark changes every teacher's Q and every agent's features
        assert (np.abs(q_moved - q) > 1e-4).mean() > 0.9 and (np.abs(phi_moved - phi).max(-1) > 1e-4).mean() > 0.9

"""The from-scratch example environment (cmcl/envs/examples/reach.py), mpe2's speaker-listener (agents of
different sizes), mpe2's simple_spread with Discrete actions (Gumbel-softmax actors in the rollout workers too)
and MaMuJoCo's 2-agent HalfCheetah (a physics environment) trained through the service on the session's embedded
Ray."""

import pytest

from cmcl.config import load_config
from cmcl.run.rundir import RunDirectory
from services.launch import run_service
from tests.tiny import tiny_overrides

pytestmark = pytest.mark.ray


@pytest.mark.parametrize("factory,extra", [
    ("cmcl.envs.examples.reach:parallel_env", ["env.success_key=reached"]),
    # extended (the default run's budget): two teams, one of them CMCL, on the service; the reach env above stays
    pytest.param("mpe2.simple_speaker_listener_v4:parallel_env",
                 ["env.factory_kwargs={continuous_actions=true, max_cycles=25}", "teams.speaker.algorithm=cmcl",
                  "teams.listener.algorithm=maddpg"], marks=pytest.mark.extended),
    # extended (the default run's budget): discrete actions and a physics env outside MPE, covered inline by default
    pytest.param("mpe2.simple_spread_v3:parallel_env", ["env.factory_kwargs={continuous_actions=false, max_cycles=25}"],
                 marks=pytest.mark.extended),
    pytest.param("gymnasium_robotics:mamujoco_v1.parallel_env",
                 ['env.factory_kwargs={scenario="HalfCheetah", agent_conf="2x3", max_episode_steps=25}',
                  "env.episode_length=25"], marks=pytest.mark.extended)])
def test_a_factory_environment_trains_through_the_service(factory, extra, tmp_path, ray_cluster):
    config = load_config(None, [f"env.factory={factory}", *tiny_overrides(service=True), *extra, "run.episodes=24",
                                f"run.dir={tmp_path}"])
    summary = run_service(config, RunDirectory.create(config.run.dir, config), progress=None)
    brief = {k: v for k, v in summary.items() if k != "metrics_text"}
    assert summary["episodes"] >= 24 and summary["updates"] > 0, brief
    for team in config.teams:
        assert f'team="{team}"' in summary["metrics_text"], team

"""env.factory environments with Discrete action spaces: Gumbel-softmax actors (ALGORITHM.md A17) whose logits cover
each agent's n actions (padded and masked where agents differ), an int per agent for the env (start + argmax of the
sample), and CI-sized training of mpe2's simple_spread with discrete actions on the inline runner."""

import numpy as np
import pytest

from cmcl.config import ConfigError
from cmcl.learners.maddpg import MADDPG
from cmcl.system import agent_layout, make_batched_env
from tests.in_process import train_tiny
from tests.test_own_env import EARLY_EXIT, MPE, config, torch_policy_actions

DISCRETE = "env.factory_kwargs={continuous_actions=false, max_cycles=25}"


def test_a_discrete_agent_gets_start_plus_the_argmax_of_its_sample():
    env = make_batched_env(config(EARLY_EXIT, "env.factory_kwargs={space='discrete'}"), num_envs=1)
    assert env.discrete and env.act_dims == (3, 3)
    assert [env._env_action(0, np.array(p, np.float32)) for p in ([.7, .2, .1], [.1, .2, .7], [0, 1, 0])] == \
        [-1, 1, 0]
    layout = agent_layout(config(EARLY_EXIT, "env.factory_kwargs={space='discrete'}"), env)
    assert layout.discrete and layout.act_dim == 3 and layout.act_mask is None
    box = make_batched_env(config(EARLY_EXIT), num_envs=1)
    assert not box.discrete and not agent_layout(config(EARLY_EXIT), box).discrete


def test_maddpg_discrete_is_still_refused_with_a_factory_naming_the_field():
    with pytest.raises(ConfigError, match="maddpg.discrete.*Discrete action spaces gets Gumbel-softmax"):
        config(MPE["spread"], "maddpg.discrete=true")


def test_agents_with_different_discrete_sizes_never_pick_a_padded_action():
    cfg = config(MPE["speaker_listener"], DISCRETE, "teams.speaker.algorithm=cmcl", "teams.listener.algorithm=maddpg")
    env = make_batched_env(cfg, num_envs=64, seed=0)
    layout = agent_layout(cfg, env)
    assert env.act_dims == (3, 5) and layout.discrete
    np.testing.assert_array_equal(layout.act_mask, [[1, 1, 1, 0, 0], [1, 1, 1, 1, 1]])
    maddpg = MADDPG(2, env.obs_dim, 5, seed=0, discrete=True, act_mask=layout.act_mask)
    obs = env.reset()
    for noise in (1.0, 0.0):
        acted = maddpg.act(obs, noise, rng=np.random.default_rng(0))
        assert not acted[:, 0, 3:].any() and np.allclose(acted.sum(-1), 1.0, atol=1e-5)
        assert set(acted[:, 0].argmax(-1)) <= {0, 1, 2}
    own = torch_policy_actions(maddpg, obs)  # the actor update's softmax: probability 0 on padding
    assert not own[:, 0, 3:].any() and np.isfinite(own).all()
    stats = maddpg.update({"obs": np.repeat(obs[None, :8], 2, 0), "act": np.repeat(acted[None, :8], 2, 0),
                           "rew": np.zeros((2, 8, 2), np.float32), "next_obs": np.repeat(obs[None, :8], 2, 0)})
    assert all(np.isfinite(v).all() for v in stats.values())


def test_mpe2_spread_with_discrete_actions_trains_on_the_inline_runner(tmp_path):
    cfg = config(MPE["spread"], DISCRETE, "run.episodes=16", "teams.agent.algorithm=cmcl")
    row, roles = train_tiny(cfg, tmp_path / "run")
    learner = roles.learner
    assert learner.layout.discrete and learner.maddpg.discrete and learner.layout.act_dim == 5
    assert isinstance(roles.rollout[0].policy, MADDPG) and roles.rollout[0].policy.discrete
    assert row["episodes"] >= 16 and row["env_steps"] == 16 * 25 and row["updates"] > 0
    replay = roles.replay.replay
    stored = replay.storage.act[: replay.size]
    np.testing.assert_allclose(stored.sum(-1), 1.0, atol=1e-5)  # the critic sees the Gumbel-softmax samples
    assert np.isfinite(row["window"]["reward"]["agent"])


def test_the_rollout_worker_acts_with_gumbel_softmax_samples_for_a_discrete_env():
    from services.roles.rollout import RolloutWorker

    worker = RolloutWorker(config(MPE["spread"], DISCRETE, "env.num_envs=2").to_dict(), 0, 0)
    chunk, _ = worker.rollout(None)
    assert worker.layout.discrete and isinstance(worker.policy, MADDPG) and worker.policy.discrete
    assert chunk.rows == 2 * 25 and np.allclose(chunk.act.sum(-1), 1.0, atol=1e-5)

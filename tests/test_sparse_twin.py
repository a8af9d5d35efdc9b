"""The sparse navigation presets on their batched twin (`env.twin`, cmcl.envs.twins): the twin that
`cmcl.system.make_batched_env` builds from a preset against the preset's own ParallelEnv on the same seed and actions
over a whole episode (observations, rewards, dones, success and coverage), also at changed world settings
(cmcl.envs.world_settings: the task curriculum's setters); and the grids' settings.

Float32 twin against the float64 ParallelEnv: observations within 1e-3 after 70 steps (float32 rounding grows with
the steps; the float64 twin's 1e-5 parity is tests/test_sparse_tasks.py's).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cmcl.config import ConfigError, load_config
from cmcl.envs.cmae_grids import LEFT, PushBoxEnv
from cmcl.envs.sparse_nav import BatchedSparseNav
from cmcl.system import make_batched_env, make_parallel_env

ROOT = Path(__file__).resolve().parents[1]
TWIN_PRESETS = ("vacl_n4", "vacl_n8", "spmarl_n8")


@pytest.mark.parametrize("task", TWIN_PRESETS)
@pytest.mark.parametrize("settings", [{}, {"spawn_scale": 0.1, "cover_radius": 0.3}])
def test_the_presets_twin_matches_its_parallel_env_over_an_episode(task, settings):
    config = load_config(ROOT / "configs" / f"{task}_maddpg.toml")
    assert config.env.twin
    twin = make_batched_env(config, num_envs=1, auto_reset=True)
    assert isinstance(twin, BatchedSparseNav)
    env = make_parallel_env(config)
    for name, value in settings.items():
        twin.set_world_settings(name, np.array([0]), np.array([value]))
        env.set_setting(name, value)
    seed = 1234
    obs = twin.reset(seed=seed)
    p_obs, _ = env.reset(seed=seed)
    names = env.possible_agents
    np.testing.assert_allclose(obs[0], np.stack([p_obs[a] for a in names]), atol=1e-6)
    rng = np.random.default_rng(0)
    rewarded = 0
    for t in range(config.env.episode_length):
        actions = rng.uniform(-1, 1, (1, len(names), 2)).astype(np.float32)
        _, rew, dones, info = twin.step(actions)
        p_obs, p_rew, _, p_trunc, p_info = env.step({a: actions[0, i].astype(np.float64) for i, a in enumerate(names)})
        np.testing.assert_allclose(info["final_obs"][0], np.stack([p_obs[a] for a in names]), atol=1e-3)
        np.testing.assert_allclose(rew[0], [p_rew[a] for a in names], atol=1e-6)
        assert bool(dones[0]) == p_trunc[names[0]] == (t == config.env.episode_length - 1)
        rewarded += int(p_info[names[0]]["reward_team"] > 0)
    ep = info["episode"]
    assert bool(ep["success"][0]) == p_info[names[0]]["success"]
    assert ep["coverage"][0] == pytest.approx(p_info[names[0]]["coverage"])
    if settings:  # agents and landmarks start packed together with a wide cover: the team is paid
        assert rewarded > 0


def test_a_world_setting_takes_effect_at_that_worlds_next_reset_only():
    twin = BatchedSparseNav(4, seed=0, auto_reset=True)
    far = np.abs(twin.get_state()["landmarks"]).max()
    twin.set_world_settings("spawn_scale", np.array([1, 3]), np.array([0.01, 0.01]))
    assert np.abs(twin.get_state()["landmarks"]).max() == far  # the running episodes keep theirs
    for _ in range(twin.episode_length):
        twin.step(np.zeros((4, twin.num_agents, 2), np.float32))
    spans = np.abs(twin.get_state()["landmarks"]).max(axis=(1, 2))
    assert (spans[[1, 3]] <= 0.03).all() and (spans[[0, 2]] > 0.03).all()
    assert twin.world_settings()["spawn_scale"].tolist() == [1.0, 0.01, 1.0, 0.01]


def test_push_box_is_solved_after_push_cells_moves_of_the_box():
    env = PushBoxEnv()
    env.set_setting("push_cells", 1)
    env.reset()
    env.pos[:] = [[9, 6], [9, 8]]  # both right of the box (x 6..8), within its rows
    _, rewards, terms, _, infos = env.step({"agent_0": LEFT, "agent_1": LEFT})
    assert env.box.tolist() == [6, 7] and terms["agent_0"] and rewards["agent_0"] == 1.0
    env.set_setting("push_cells", 6)
    env.reset()
    env.pos[:] = [[9, 6], [9, 8]]
    _, rewards, terms, _, _ = env.step({"agent_0": LEFT, "agent_1": LEFT})
    assert env.box.tolist() == [6, 7] and not terms["agent_0"] and rewards["agent_0"] == 0.0


def test_twin_without_a_registered_factory_is_refused_naming_it():
    with pytest.raises(ConfigError, match=r"env.twin .*push_box_env"):
        load_config(ROOT / "configs" / "push_box_maddpg.toml", ["env.twin=true"])

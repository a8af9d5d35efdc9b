"""`done` per agent: an agent that terminates before the others (PettingZoo removes it from the next dict) cuts
the bootstrap of its own critic target only (eq. 5 with done_{v,j}); its later rows are an absorbing state
(zeros, reward 0, done 1). Shown on tests/early_exit.py, written from scratch: agent_0 terminates after 2 steps,
agent_1 plays on until its truncation after 5."""

import numpy as np

from cmcl.learners.maddpg import MADDPG
from cmcl.system import make_batched_env
from tests.in_process import train_tiny
from tests.test_own_env import EARLY_EXIT, config


def test_the_adapter_flags_each_agents_own_termination():
    env = make_batched_env(config(EARLY_EXIT), num_envs=2, seed=0)
    env.reset()
    flags, ended = [], []
    for _ in range(5):
        _, rew, done, info = env.step(np.zeros((2, 2, 1), np.float32))
        flags.append(info["terminated"].copy())
        ended.append(done.copy())
    flags = np.stack(flags)  # [t, B, N]
    assert flags[:, :, 0].tolist() == [[False] * 2] + [[True] * 2] * 4, "agent_0: its termination, then gone"
    assert not flags[:, :, 1].any(), "agent_1 is truncated: it bootstraps"
    assert np.stack(ended)[:, 0].tolist() == [False] * 4 + [True], "the world ends when the last agent leaves"


def test_an_early_termination_cuts_only_that_agents_bootstrap():
    maddpg = MADDPG(2, 1, 1, seed=0)
    rew = np.ones((3, 2), np.float32)
    next_obs = np.full((3, 2, 1), 0.4, np.float32)
    done = np.array([[1, 0], [0, 0], [1, 1]], np.float32)  # [M, N]
    y, y_free = maddpg.td_targets(rew, next_obs, done), maddpg.td_targets(rew, next_obs)
    np.testing.assert_allclose(y[0], [1.0, y_free[0, 1], 1.0])  # agent 0: r where it terminated
    np.testing.assert_allclose(y[1], [y_free[1, 0], y_free[1, 1], 1.0])  # agent 1: only where it did
    owner = maddpg.td_targets(np.repeat(rew[None], 2, 0), np.repeat(next_obs[None], 2, 0), np.repeat(done[None], 2, 0))
    np.testing.assert_allclose(owner, y, rtol=1e-6)  # per-owner batches read each owner's own column


def test_a_run_stores_each_agents_done(tmp_path):
    summary, roles = train_tiny(config(EARLY_EXIT, "env.episode_length=5", "run.episodes=8"), tmp_path / "run")
    replay = roles.replay.replay
    rows = slice(0, replay.size)
    assert summary["episodes"] == 8 and replay.size == 8 * 5
    stored, step = replay.storage.done[rows], np.round(replay.storage.next_obs[rows, 1, 0] * 5)
    np.testing.assert_array_equal(stored[:, 0], step >= 2)  # agent_0 from its termination at step 2 on
    assert not stored[:, 1].any()

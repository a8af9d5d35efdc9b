"""An env.factory run's episode length as a new user meets it (subprocesses of `python -m cmcl train`): the env's own
(max_cycles, max_steps, spec.max_episode_steps) when env.episode_length is set nowhere, else the one set, and
env.episode_length's default only when the env declares none; one line names the length used either way, and the
run's config.toml holds it (cmcl.run.preflight.with_episode_length)."""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TINY = ["env.num_envs=2", "maddpg.batch_size=16", "maddpg.warmup=32", "maddpg.hidden=16", "replay.capacity=600",
        "run.episodes=2"]

NO_LENGTH_ENV = '''
import numpy as np
from gymnasium.spaces import Box
from pettingzoo import ParallelEnv


class Endless(ParallelEnv):
    """One agent, never done: it declares no episode length of its own."""

    metadata = {"name": "endless_v0"}
    possible_agents = ["agent_0"]

    def observation_space(self, agent):
        return Box(-1.0, 1.0, (2,), np.float32)

    def action_space(self, agent):
        return Box(-1.0, 1.0, (1,), np.float32)

    def reset(self, seed=None, options=None):
        self.agents = list(self.possible_agents)
        return {"agent_0": np.zeros(2, np.float32)}, {"agent_0": {}}

    def step(self, actions):
        return ({"agent_0": np.zeros(2, np.float32)}, {"agent_0": 0.0}, {"agent_0": False}, {"agent_0": False},
                {"agent_0": {}})


def parallel_env():
    return Endless()
'''


def train(run_dir: Path, *overrides: str, pythonpath: Path | None = None) -> tuple[str, int]:
    """`python -m cmcl train --runner inline` with the tiny settings and `overrides`; (its output, the episode
    length in the run's config.toml)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(str(p) for p in (pythonpath, ROOT) if p)}
    sets = [arg for text in (*TINY, *overrides, f"run.dir={run_dir}") for arg in ("--set", text)]
    done = subprocess.run([sys.executable, "-m", "cmcl", "train", "--runner", "inline", *sets, "--no-eval"],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    config = tomllib.loads((run_dir / "config.toml").read_text())
    return done.stdout + done.stderr, config["env"]["episode_length"]


def test_the_envs_own_max_cycles_is_the_episode_length_when_none_is_set(tmp_path):
    out, length = train(tmp_path / "run", "env.factory=cmcl.envs.examples.reach:parallel_env",
                        "env.factory_kwargs={max_cycles=12}")
    assert "episode length: 12 steps, the env's own max_cycles" in out
    assert length == 12


def test_a_set_episode_length_is_kept_and_the_envs_own_named(tmp_path):
    pytest.importorskip("pettingzoo.sisl", reason="PettingZoo's SISL envs (pettingzoo[sisl]) are not installed")
    out, length = train(tmp_path / "run", "env.factory=pettingzoo.sisl.pursuit_v5:parallel_env",
                        "env.factory_kwargs={max_cycles=40}", "env.episode_length=6", "teams.pursuer.algorithm=maddpg")
    assert "episode length: 6 steps, as env.episode_length sets it; the env's own max_cycles is 40" in out
    assert length == 6


def test_an_env_without_a_length_of_its_own_gets_the_default_said_so(tmp_path):
    (tmp_path / "endless_env.py").write_text(NO_LENGTH_ENV)
    out, length = train(tmp_path / "run", "env.factory=endless_env:parallel_env", pythonpath=tmp_path)
    assert "episode length: 30 steps, env.episode_length's default" in out and "declares none" in out
    assert length == 30

"""The evaluation at the end of `train`, as a new user meets it (subprocesses): a line when it starts, naming
--no-eval; on an env.factory environment its progress while it runs and a time bound that fits the env's step cost
(cmcl.run.report.bounded_evaluation), so a slow environment is evaluated on fewer worlds instead of for minutes."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

from cmcl.run.report import pooled

ROOT = Path(__file__).resolve().parents[1]

SLOW_ENV = '''
import time

import numpy as np
from gymnasium.spaces import Box
from pettingzoo import ParallelEnv


class Slow(ParallelEnv):
    """One agent; each step costs 5 ms of wall clock (a physics step's cost, simulated), 100 steps an episode."""

    metadata = {"name": "slow_v0"}
    possible_agents = ["agent_0"]
    max_cycles = 100

    def observation_space(self, agent):
        return Box(-1.0, 1.0, (2,), np.float32)

    def action_space(self, agent):
        return Box(-1.0, 1.0, (1,), np.float32)

    def reset(self, seed=None, options=None):
        self.agents, self.t = list(self.possible_agents), 0
        return {"agent_0": np.zeros(2, np.float32)}, {"agent_0": {}}

    def step(self, actions):
        time.sleep(0.005)
        self.t += 1
        end = self.t >= self.max_cycles
        return ({"agent_0": np.zeros(2, np.float32)}, {"agent_0": float(actions["agent_0"][0])},
                {"agent_0": False}, {"agent_0": end}, {"agent_0": {}})


def parallel_env():
    return Slow()
'''


def test_a_slow_envs_evaluation_is_shown_and_bounded(tmp_path):
    (tmp_path / "slow_env.py").write_text(SLOW_ENV)
    sets = ["env.factory=slow_env:parallel_env", "env.num_envs=2", "maddpg.warmup=32", "maddpg.batch_size=16",
            "maddpg.hidden=16", "replay.capacity=600", "run.episodes=2",
            "run.max_seconds=20", f"run.dir={tmp_path / 'run'}"]  # a 20 s budget: the evaluation's bound is 10 s
    env = {**os.environ, "PYTHONPATH": os.pathsep.join((str(tmp_path), str(ROOT)))}
    done = subprocess.run([sys.executable, "-m", "cmcl", "train", "--runner", "inline",
                           *[arg for text in sets for arg in ("--set", text)]], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("evaluation: "))
    assert "--no-eval skips it" in lines[start] and "within about 10 s" in lines[start]
    progress = [line for line in lines if line.startswith("evaluation (trained): ")]
    assert progress and progress[0].startswith("evaluation (trained): 10 of 200 episodes")
    worlds = int(re.search(r"held-out evaluation \((\d+) new worlds", done.stdout).group(1))
    assert worlds < 200 and worlds % 10 == 0  # 200 worlds cost 100 s here: the bound cut it short


def test_pooled_results_weigh_each_part_by_its_episodes():
    parts = [{"episodes": 10, "policy": "trained", "success": 0.2, "success_std": 0.4, "reward": {"agent": 1.0}},
             {"episodes": 30, "policy": "trained", "success": 0.6, "success_std": 0.0, "reward": {"agent": 3.0}}]
    result = pooled(parts)
    values = [1.0] * 2 + [0.0] * 8 + [0.6] * 30  # a set of episodes with those means and deviations
    assert result["episodes"] == 40 and abs(result["success"] - sum(values) / 40) < 1e-12
    mean = sum(values) / 40
    assert abs(result["success_std"] - (sum((v - mean) ** 2 for v in values) / 40) ** 0.5) < 1e-12
    assert result["reward"] == {"agent": 2.5}

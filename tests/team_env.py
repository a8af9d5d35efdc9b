"""Three agents in two teams by id prefix (scout_0, scout_1, walker_0), each stepping toward its own goal on a line:
the own-environment test of a user's env with team names of its own and no [teams] table, and of an env whose own
code fails (`fail_in` = "init" | "reset" | "step": that call raises, as a user's bug would)."""

import numpy as np
from gymnasium.spaces import Box
from pettingzoo import ParallelEnv


class Teams(ParallelEnv):
    metadata = {"name": "teams_v0"}

    def __init__(self, max_cycles=5, fail_in="", render_mode=None):
        if fail_in == "init":
            raise KeyError("map_file")  # e.g. a missing entry in the user's own settings
        self.possible_agents = ["scout_0", "scout_1", "walker_0"]
        self.max_cycles, self.fail_in, self.render_mode = max_cycles, fail_in, render_mode

    def observation_space(self, agent):
        return Box(-1.0, 1.0, (2,), np.float32)

    def action_space(self, agent):
        return Box(-0.2, 0.2, (1,), np.float32)

    def reset(self, seed=None, options=None):
        if self.fail_in == "reset":
            raise RuntimeError("no map loaded")
        self.rng, self.t, self.agents = np.random.default_rng(seed), 0, list(self.possible_agents)
        self.state = {a: self.rng.uniform(-1, 1, 2).astype(np.float32) for a in self.agents}
        return {a: s.copy() for a, s in self.state.items()}, {a: {} for a in self.agents}

    def step(self, actions):
        if self.fail_in == "step":
            raise ZeroDivisionError("division by zero")
        self.t += 1
        for a, step in actions.items():
            self.state[a][0] = np.clip(self.state[a][0] + step[0], -1.0, 1.0)
        rew = {a: -abs(float(s[0] - s[1])) for a, s in self.state.items()}
        over = self.t >= self.max_cycles
        obs = {a: self.state[a].copy() for a in self.agents}
        term, trunc = {a: False for a in self.agents}, {a: over for a in self.agents}
        infos = {a: {} for a in self.agents}
        if over:
            self.agents = []
        return obs, rew, term, trunc, infos


def parallel_env(**kwargs):
    return Teams(**kwargs)

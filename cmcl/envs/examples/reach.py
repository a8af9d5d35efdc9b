"""Two walkers on a line, each to reach its own goal: an environment written from scratch for docs/OWN_ENVIRONMENT.md.

Train it: python -m cmcl train --runner inline --set env.factory=cmcl.envs.examples.reach:parallel_env --set
env.success_key=reached
"""

import numpy as np
from gymnasium.spaces import Box
from pettingzoo import ParallelEnv


class Reach(ParallelEnv):
    metadata = {"name": "reach_v0"}

    def __init__(self, max_cycles=25, render_mode=None):
        self.possible_agents, self.max_cycles, self.render_mode = ["agent_0", "agent_1"], max_cycles, render_mode

    def observation_space(self, agent):
        return Box(-1.0, 1.0, (2,), np.float32)  # (own position, own goal)

    def action_space(self, agent):
        return Box(-0.2, 0.2, (1,), np.float32)  # a step along the line

    def reset(self, seed=None, options=None):
        self.rng, self.t, self.agents = np.random.default_rng(seed), 0, list(self.possible_agents)
        self.state = {a: self.rng.uniform(-1, 1, 2).astype(np.float32) for a in self.agents}
        return {a: s.copy() for a, s in self.state.items()}, {a: {} for a in self.agents}

    def step(self, actions):
        self.t += 1
        for a, step in actions.items():
            self.state[a][0] = np.clip(self.state[a][0] + step[0], -1.0, 1.0)
        dist = {a: abs(float(s[0] - s[1])) for a, s in self.state.items()}
        reached = all(d < 0.1 for d in dist.values())  # both at their goals: the episode terminates
        rew = {a: -sum(dist.values()) + (5.0 if reached else 0.0) for a in self.agents}  # a shared team reward
        term = {a: reached for a in self.agents}
        trunc = {a: self.t >= self.max_cycles and not reached for a in self.agents}
        obs, infos = {a: self.state[a].copy() for a in self.agents}, {a: {"reached": reached} for a in self.agents}
        if reached or self.t >= self.max_cycles:
            self.agents = []
        return obs, rew, term, trunc, infos

    def render(self):  # rgb_array: one band per agent, its goal green, the agent white
        img = np.zeros((8 * len(self.possible_agents), 64, 3), np.uint8)
        for i, (pos, goal) in enumerate(self.state.values()):
            img[8 * i : 8 * i + 8, int((goal + 1) * 31.5)] = (0, 255, 0)
            img[8 * i : 8 * i + 8, int((pos + 1) * 31.5)] = 255
        return img


def parallel_env(**kwargs):
    return Reach(**kwargs)

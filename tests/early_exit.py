"""Two agents, one of which leaves early: agent_0 terminates after `exit_at` steps (and is removed), agent_1 plays
on until the truncation at `max_cycles`. Written from scratch for the per-agent `done` and action-space tests.
`space`: the agents' action spaces, "box" | "discrete" (Discrete(3, start=-1)) | "multidiscrete" | "mixed"."""

import numpy as np
from gymnasium.spaces import Box, Discrete, MultiDiscrete
from pettingzoo import ParallelEnv


class EarlyExit(ParallelEnv):
    metadata = {"name": "early_exit_v0"}

    def __init__(self, exit_at=2, max_cycles=5, space="box", render_mode=None):
        self.possible_agents, self.exit_at, self.max_cycles = ["agent_0", "agent_1"], exit_at, max_cycles
        self.space = space

    def observation_space(self, agent):
        return Box(0.0, 1.0, (1,), np.float32)  # the time, t / max_cycles

    def action_space(self, agent):
        kind = {"mixed": "discrete" if agent == "agent_1" else "box"}.get(self.space, self.space)
        spaces = {"box": Box(-1.0, 1.0, (1,)), "discrete": Discrete(3, start=-1),
                  "multidiscrete": MultiDiscrete([2, 2])}
        return spaces[kind]

    def reset(self, seed=None, options=None):
        self.t, self.agents = 0, list(self.possible_agents)
        return {a: np.zeros(1, np.float32) for a in self.agents}, {a: {} for a in self.agents}

    def step(self, actions):
        self.t += 1
        rew = {a: 1.0 for a in self.agents}
        term = {a: a == "agent_0" and self.t >= self.exit_at for a in self.agents}
        trunc = {a: self.t >= self.max_cycles and not term[a] for a in self.agents}
        obs = {a: np.full(1, self.t / self.max_cycles, np.float32) for a in self.agents}
        self.agents = [a for a in self.agents if not (term[a] or trunc[a])]
        return obs, rew, term, trunc, {a: {} for a in rew}


def parallel_env(**kwargs):
    return EarlyExit(**kwargs)

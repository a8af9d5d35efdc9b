"""A ParallelEnv written to probe the adapter's edges: agents that leave early with their own
success, observations that do not fit their declared Box, episodes shorter than env.episode_length.

`leave_at[i]`: the step after which agent_i terminates and leaves (the episode ends when the last one has left, or at
`max_cycles`); `succeed`: the agents whose info says {"hit": 1.0} (the others 0.0) at every step; `fault` at step
`fault_at` (0 = the reset) for agent_0: "short" shape (1,) for the declared (2,), "long" (3,), "wide" int64 values
±60 for Box(-1, 1), "nan", "text" (a string array); observations are otherwise (t / max_cycles, -t / max_cycles).
`crash_after`: the number of episodes this copy plays whole; at step `fault_at` of the next one its step raises
RuntimeError("probe crash") (0 = never).
"""

import numpy as np
from gymnasium.spaces import Box
from pettingzoo import ParallelEnv


class Probe(ParallelEnv):
    metadata = {"name": "probe_v0"}

    def __init__(self, agents=2, leave_at=(), succeed=(), max_cycles=5, fault="", fault_at=0, crash_after=0,
                 render_mode=None):
        self.possible_agents = [f"agent_{i}" for i in range(agents)]
        self.leave_at = {f"agent_{i}": int(t) for i, t in enumerate(leave_at)}
        self.succeed = {f"agent_{i}" for i in succeed}
        self.max_cycles, self.fault, self.fault_at = max_cycles, fault, fault_at
        self.crash_after, self.episodes = int(crash_after), -1  # resets so far, minus the first

    def observation_space(self, agent):
        return Box(-1.0, 1.0, (2,), np.float32)

    def action_space(self, agent):
        return Box(-1.0, 1.0, (1,), np.float32)

    def _obs(self, agent):
        if agent == "agent_0" and self.fault and self.t == self.fault_at:
            return {"short": np.zeros(1, np.float32), "long": np.zeros(3, np.float32),
                    "wide": np.array([60, -60], np.int64), "nan": np.array([0.0, np.nan], np.float32),
                    "text": np.array(["a", "b"])}[self.fault]
        return np.array([self.t, -self.t], np.float32) / self.max_cycles

    def reset(self, seed=None, options=None):
        self.t, self.agents, self.episodes = 0, list(self.possible_agents), self.episodes + 1
        return {a: self._obs(a) for a in self.agents}, {a: {} for a in self.agents}

    def step(self, actions):
        self.t += 1
        if self.crash_after and self.episodes >= self.crash_after and self.t >= self.fault_at:
            raise RuntimeError("probe crash")
        rew = {a: 0.0 for a in self.agents}
        term = {a: self.t >= self.leave_at.get(a, self.max_cycles + 1) for a in self.agents}
        trunc = {a: self.t >= self.max_cycles and not term[a] for a in self.agents}
        infos = {a: {"hit": 1.0 if a in self.succeed else 0.0} for a in self.agents}
        obs = {a: self._obs(a) for a in self.agents}
        self.agents = [a for a in self.agents if not (term[a] or trunc[a])]
        return obs, rew, term, trunc, infos


def parallel_env(**kwargs):
    return Probe(**kwargs)

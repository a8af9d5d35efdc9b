"""The environments of the peer comparison and the one held-out evaluation that scores both libraries.

Environments (``--env``):

* ``sparse_spread``: ours, ``cmcl.envs.sparse_spread_v0.parallel_env(num_agents=4, max_cycles=30,
  shared_reward=False)``; the final step's ``info["episode"]`` gives landmark coverage and success.
* ``vacl_n4``: VACL's all-or-nothing sparse navigation, ``cmcl.envs.sparse_nav_v0.parallel_env(variant="vacl",
  num_agents=4)`` (70 steps; docs/SPARSE_TASKS.md); success: every landmark covered at the final step.
* ``simple_spread_v3``: mpe2's ``simple_spread_v3.parallel_env(N=3, max_cycles=25, continuous_actions=True)``
  (local_ratio 0.5, its default), the MPE cooperative-navigation task with N = 3 and 25-step episodes as in
  AgileRL's MPE examples; actions ``Box(0, 1, (5,))`` per agent, observations float32[18].

Held-out return (the one definition both sides are scored by): for an episode of T steps with N agents and
rewards r[t, i], ``return = (1 / N) * sum_i sum_t r[t, i]``, i.e. each agent's reward summed over the episode,
averaged over agents; reported as the mean (and std) over ``episodes`` fresh episodes reset with the seeds
``eval_seeds(train_seed, episodes)``, which no training episode uses. The policy acts without exploration noise.
The random policy draws each action uniformly in the agent's Box (numpy Generator seeded with the train seed).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from pettingzoo.utils.wrappers import BaseParallelWrapper

EVAL_SEED_BASE = 10_000_000  # held-out episodes: seeds EVAL_SEED_BASE + 100_000 * train_seed + k
EVAL_SEED_STRIDE = 100_000

# obs: {agent_id: float32[obs_dim]} -> {agent_id: env action (the agent's Box shape)}
Policy = Callable[[Mapping[str, np.ndarray]], dict[str, np.ndarray]]


@dataclass(frozen=True)
class PeerEnv:
    """One environment choice: how to build it and what to call it in the results."""

    name: str  # the --env value
    label: str  # the full constructor call, for the results JSON
    num_agents: int
    max_cycles: int  # steps per episode (the env truncates there)
    has_coverage: bool  # the final step's info["episode"] carries coverage / success (our sparse env only)
    factory: str  # "package.module:callable", as our env.factory takes it
    factory_kwargs: tuple[tuple[str, Any], ...]

    def make(self, **extra: Any) -> Any:
        """One new ParallelEnv (extra: e.g. render_mode)."""
        import importlib

        module_name, _, attr = self.factory.partition(":")
        return getattr(importlib.import_module(module_name), attr)(**dict(self.factory_kwargs), **extra)


ENVS: dict[str, PeerEnv] = {
    "sparse_spread": PeerEnv(
        "sparse_spread", "sparse_spread_v0(num_agents=4, max_cycles=30, shared_reward=False)", 4, 30, True,
        "cmcl.envs.sparse_spread_v0:parallel_env", (("num_agents", 4), ("max_cycles", 30), ("shared_reward", False))),
    "vacl_n4": PeerEnv(
        "vacl_n4", "sparse_nav_v0(variant='vacl', num_agents=4)", 4, 70, True, "cmcl.envs.sparse_nav_v0:parallel_env",
        (("variant", "vacl"), ("num_agents", 4))),
    "simple_spread_v3": PeerEnv(
        "simple_spread_v3", "mpe2.simple_spread_v3(N=3, max_cycles=25, continuous_actions=True, local_ratio=0.5)", 3,
        25, False, "mpe2.simple_spread_v3:parallel_env",
        (("N", 3), ("max_cycles", 25), ("continuous_actions", True))),
}


def eval_seeds(train_seed: int, episodes: int) -> list[int]:
    """The reset seeds of the held-out episodes of training seed `train_seed` (disjoint from any training seed)."""
    base = EVAL_SEED_BASE + EVAL_SEED_STRIDE * int(train_seed)
    return [base + k for k in range(int(episodes))]


def heldout_evaluation(env_spec: PeerEnv, policy: Policy, seeds: list[int]) -> dict[str, Any]:
    """Roll `policy` out on one fresh episode per seed; the held-out return (module docstring) and, on our sparse
    env, final-step coverage and success. Returns means, stds, the per-episode returns and the seed range."""
    env = env_spec.make()
    returns, cov, succ = [], [], []
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        total = {a: 0.0 for a in env.possible_agents}
        summary = None
        while env.agents:
            obs, rew, _, _, info = env.step(policy(obs))
            for agent, r in rew.items():
                total[agent] += float(r)
            for i in info.values():
                if "episode" in i:
                    summary = i["episode"]
        returns.append(sum(total.values()) / len(total))
        if env_spec.has_coverage:
            if summary is None:
                raise RuntimeError(f"{env_spec.name}: an episode ended without info['episode']")
            cov.append(float(summary["coverage"]))
            succ.append(float(bool(summary["success"])))
    env.close()
    out: dict[str, Any] = {
        "episodes": len(seeds),
        "seeds": [seeds[0], seeds[-1]],
        "return_mean": float(np.mean(returns)),
        "return_std": float(np.std(returns)),
        "returns": [round(r, 4) for r in returns],
    }
    if env_spec.has_coverage:
        out.update(coverage_mean=float(np.mean(cov)), coverage_std=float(np.std(cov)),
                   success_rate=float(np.mean(succ)))
    return out


def random_policy(env_spec: PeerEnv, seed: int) -> Policy:
    """Uniform actions in each agent's Box, from a numpy Generator seeded with `seed`."""
    env = env_spec.make()
    spaces = {a: env.action_space(a) for a in env.possible_agents}
    env.close()
    rng = np.random.default_rng(seed)

    def act(obs: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {a: rng.uniform(spaces[a].low, spaces[a].high).astype(np.float32) for a in obs}

    return act


class ForwardingWrapper(BaseParallelWrapper):
    """A ParallelEnv wrapper whose agents, spaces, metadata and render mode are the wrapped env's (explicit
    forwards: ParallelEnv's class attributes would otherwise shadow __getattr__)."""

    @property
    def possible_agents(self):
        return self.env.possible_agents

    @property
    def agents(self):
        return self.env.agents

    @property
    def metadata(self):
        return self.env.metadata

    @property
    def render_mode(self):
        return self.env.render_mode

    def observation_space(self, agent):
        return self.env.observation_space(agent)

    def action_space(self, agent):
        return self.env.action_space(agent)


class EpisodeSummaryCarrier(ForwardingWrapper):
    """Copies the last finished episode's final-step coverage/success into the next reset's infos.

    AgileRL's async vec env auto-resets in the worker and returns the reset's infos in place of the final
    step's, so our info["episode"] never reaches the training loop. Nothing else is changed.
    """

    def __init__(self, env):
        super().__init__(env)
        self._last: dict[str, float] | None = None

    def step(self, actions):
        obs, rew, terms, truncs, infos = self.env.step(actions)
        for info in infos.values():
            if "episode" in info:
                ep = info["episode"]
                self._last = {"coverage": float(ep["coverage"]), "success": float(bool(ep["success"]))}
                break
        return obs, rew, terms, truncs, infos

    def reset(self, seed=None, options=None):
        obs, infos = self.env.reset(seed=seed, options=options)
        if self._last is not None:
            for name in infos:
                infos[name] = {
                    **infos[name],
                    "prev_ep_coverage": self._last["coverage"],
                    "prev_ep_success": self._last["success"],
                }
            self._last = None
        return obs, infos

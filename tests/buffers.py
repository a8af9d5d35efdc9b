"""A replay buffer built in a test from explicit per-agent sampler settings (scalar = every agent's, or one per
agent), as cmcl.system.build_replay builds one from a config: the storage, one sampler per agent built by its
rule (cmcl.replay.registry.build_sampler), then `ReplayBuffer(storage, samplers)`."""

from __future__ import annotations

import numpy as np

from cmcl.replay.buffer import ReplayBuffer
from cmcl.replay.priority import EPS_P, LAM_MAX
from cmcl.replay.registry import build_sampler
from cmcl.replay.sampling import SamplerArgs
from cmcl.replay.storage import TransitionStorage


def make_buffer(*, capacity: int = 5000, n_agents: int, obs_dim: int, act_dim: int, n_folds: int = 5,
                algorithms="maddpg", alpha=1.0, eps: float = EPS_P, backend: str = "cdf", eta=0.5,
                difficulty_norm="rank", cp_input="std", difficulty_source="difficulty", min_size: int = 1,
                lam_max: float = LAM_MAX, difficulty_transform="none", control_seed=0, floor=0.0,
                difficulty_squared=True, options=None) -> ReplayBuffer:
    """The buffer of `n_agents` agents with these settings (see SamplerArgs); options: one rule's options for all."""
    def each(value) -> list:
        return list(value) if isinstance(value, list | tuple | np.ndarray) else [value] * n_agents

    storage = TransitionStorage(capacity=capacity, n_agents=n_agents, obs_dim=obs_dim, act_dim=act_dim,
                                n_folds=n_folds)
    settings = zip(each(algorithms), each(alpha), each(eta), each(difficulty_norm), each(cp_input),
                   each(difficulty_source), each(difficulty_transform), each(floor), each(difficulty_squared),
                   strict=True)
    samplers = [build_sampler(algo, SamplerArgs(
        capacity=capacity, alpha=float(a), backend=backend, eps=eps, agent=agent, eta=float(e), difficulty_source=src,
        difficulty_norm=norm, difficulty_squared=bool(sq), cp_input=cp, lam_max=lam_max,
        reversed_difficulty=transform == "reversed", permuted=transform == "permuted", floor=float(u)), options)
        for agent, (algo, a, e, norm, cp, src, transform, u, sq) in enumerate(settings)]
    return ReplayBuffer(storage, samplers, min_size=min_size, lam_max=lam_max, control_seed=control_seed)

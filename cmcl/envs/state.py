"""Copy a world state between a PettingZoo env and a batched twin (B = 1).

Where it sits: used by the parity tests and by anyone who wants to render or inspect a twin's world
with the PettingZoo version. The dict has the twins' `get_state()` form with B = 1:
positions [1, N, 2], velocities [1, N, 2], landmarks [1, L, 2] (obstacles in predator-prey),
step int64[1], and the episode accumulators ep_* (optional on set; zero when absent); with navigation's agent_tags
also tags [1, N] (required on set).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cmcl.envs.common import check_state_arrays
from cmcl.envs.pz_base import SparseParallelEnv


def _base(env: Any) -> SparseParallelEnv:
    base = getattr(env, "unwrapped", env)
    if not isinstance(base, SparseParallelEnv):
        raise ValueError(f"env must be a sparse_spread_v0 or sparse_tag_v0 env, got {type(env).__name__}")
    return base


def get_world_state(env: Any) -> dict[str, np.ndarray]:
    """The env's state as float64 arrays with a leading batch axis of 1 (copies)."""
    base = _base(env)
    world = base.world
    state = {
        "positions": np.array([a.state.p_pos for a in world.agents], dtype=np.float64)[None],
        "velocities": np.array([a.state.p_vel for a in world.agents], dtype=np.float64)[None],
        "landmarks": np.array([lm.state.p_pos for lm in world.landmarks], dtype=np.float64).reshape(1, -1, 2),
        "step": np.array([base.steps], dtype=np.int64),
    }
    for key, value in base.stats.items():
        state[key] = np.array(value)[None]
    for key, value in base.episode_constants().items():
        state[key] = np.array(value, dtype=np.float64)[None]
    return state


def set_world_state(env: Any, state: dict[str, Any]) -> dict[str, np.ndarray]:
    """Load a B = 1 state into the env (all agents live again); returns the observation dict."""
    base = _base(env)
    n, num_l = len(base.world.agents), len(base.world.landmarks)
    shapes = {"positions": (1, n, 2), "velocities": (1, n, 2), "landmarks": (1, num_l, 2), "step": (1,)}
    constants = base.episode_constants()
    shapes.update({k: (1, *v.shape) for k, v in constants.items()})
    arrays = {k: v.astype(np.float64) for k, v in check_state_arrays(state, shapes, base.stats).items()}
    for key, value in base.stats.items():
        want = (1, *np.shape(value))
        if key in state and np.asarray(state[key]).shape != want:
            raise ValueError(f"state[{key!r}] must have shape {want}, got {np.asarray(state[key]).shape}")
    step = arrays["step"][0]
    if step < 0 or step >= base.max_cycles or step != int(step):
        raise ValueError(f"state['step'] must be an integer in [0, {base.max_cycles}), got {step}")
    base.place(arrays["positions"][0], arrays["velocities"][0], arrays["landmarks"][0], int(step))
    for key, value in constants.items():
        value[...] = arrays[key][0]
    for key in list(base.stats):
        if key in state:
            value = np.asarray(state[key])[0]
            base.stats[key] = value.astype(np.float64) if value.ndim else value.item()
    return base.observe_all()

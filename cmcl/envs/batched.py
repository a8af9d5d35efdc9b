"""Batched numpy twins of the sparse tasks: B worlds per `step`, for the rollout hot path.

Where it sits: rollout workers (on either runner) step these instead of PettingZoo envs; the parity
test ties them to `sparse_spread_v0` / `sparse_tag_v0`. Common interface of both classes:

* constructor: `(num_envs, <task sizes>, episode_length=30, ..., seed=None, auto_reset=False,
  dtype=np.float32)`; invalid values raise ValueError naming the argument;
* attributes: num_envs, num_agents, obs_dim, obs_dims (true length per agent; shorter rows are
  zero-padded to obs_dim), act_dim (2), teams (name -> agent indices), episode_length, dtype;
* `reset(seed=None) -> obs [B, N, obs_dim]`;
* `step(actions [B, N, 2]) -> (obs [B, N, obs_dim], rewards [B, N], dones bool[B], info)`; actions are
  clipped to [-1, 1]; `dones` is the 30-step time limit (bootstrap through it);
* `get_state()` / `set_state(state)`: positions, velocities [B, N, 2], landmarks [B, L, 2] (obstacles
  for tag), step int64[B], the episode accumulators ep_* and, for navigation with agent_tags, the agents' tags
  [B, N]; `cmcl.envs.state` moves the same dict to and from a PettingZoo env.
"""

from cmcl.envs.batched_spread import BatchedSparseSpread
from cmcl.envs.batched_tag import BatchedSparseTag

__all__ = ["BatchedSparseSpread", "BatchedSparseTag"]

"""Rows of a smaller agent count in the replay of a larger one (`run.carry_replay`).

Where it sits: a run that warm-starts from a run with fewer agents (`python -m cmcl stages`, each stage from the one
before) may also start with that run's replay rows (cmcl.run.carried_replay reads them); this module puts them
into the larger run's layout. How a row of n agents enters the layout of N >= n agents (two EntityLayouts of the
same task, cmcl.envs.entities):
- agents: the row's n agents become agents 0..n-1; agents n..N-1 are absent: their observation, action, reward and
  done are 0 and the row's agent mask `present` bool[N] (stored per row by TransitionStorage) is False for them.
  The present agents are always the first ones, so a row's count of present agents says who is there.
- each present agent's observation: its own features go to its own columns; every entity goes to the slot of the
  same identity in the larger layout (the entity showing agent j to the slot showing j; the k-th landmark of a
  type to the k-th of that type); the slots that exist only with more agents (E grows with N: navigation's
  E = 2N - 1) read 0 and are masked by the entity networks (EntityLayout.needs_agents > n; present_mask).
A row that was itself padded (a third stage carrying the second's rows) keeps its count: its absent agents stay
absent. Vectorised: one gather per observation array; the column map is built once per layout pair.
"""

from __future__ import annotations

import numpy as np

from cmcl.envs.entities import ABSENT, EntityLayout

__all__ = ["pad_rows", "source_columns"]


def _slot_in(big: EntityLayout, small: EntityLayout, agent: int, entity: int) -> int:
    """The entity slot of `agent` in `big` with the identity of slot `entity` in `small`."""
    shown = small.entity_agent[agent, entity]
    if shown >= 0:
        return int(np.flatnonzero(big.entity_agent[agent] == shown)[0])
    kind = small.entity_type[agent, entity].argmax()
    same = lambda layout: np.flatnonzero((layout.entity_agent[agent] < 0)  # noqa: E731
                                         & (layout.entity_type[agent].argmax(-1) == kind))
    rank = int(np.flatnonzero(same(small) == entity)[0])
    return int(same(big)[rank])


def source_columns(small: EntityLayout, big: EntityLayout) -> np.ndarray:
    """int64[n, big.obs_dim]: for present agent i and each column of its observation in `big`, the column of its
    observation in `small` that fills it, or small.obs_dim (a column of zeros). ValueError unless `big` has at least
    as many agents and the same own features, entity features and entity types."""
    n = small.num_agents
    if big.num_agents < n or small.own_index.shape[1] != big.own_index.shape[1] \
            or small.entity_dim != big.entity_dim or small.type_names != big.type_names:
        raise ValueError(f"rows of {n} agents do not fit the layout of {big.num_agents} agents (their own features, "
                         "entity features or entity types differ)")
    src = np.full((n, big.obs_dim), small.obs_dim, np.int64)
    for i in range(n):  # the layouts' agents x entities, once per layout pair (not per transition)
        src[i, big.own_index[i]] = small.own_index[i]
        for e in range(small.num_entities):
            cols_big, cols_small = big.entity_index[i, _slot_in(big, small, i, e)], small.entity_index[i, e]
            seen = cols_big != ABSENT
            src[i, cols_big[seen]] = np.where(cols_small[seen] == ABSENT, small.obs_dim, cols_small[seen])
    return src


def pad_rows(rows: dict[str, np.ndarray], present: np.ndarray, small: EntityLayout,
             big: EntityLayout) -> dict[str, np.ndarray]:
    """Rows of n = small.num_agents agents in the layout of N = big.num_agents (module docstring).

    rows: obs, next_obs float32[T, n, small.obs_dim], act float32[T, n, A], rew float32[T, n], done float32[T, n];
    present bool[T, n] (the agents each row holds, a prefix) -> the same keys at N (obs [T, N, big.obs_dim], ...)
    plus "present" bool[T, N].
    """
    n, big_n = small.num_agents, big.num_agents
    t = np.shape(present)[0]
    src = source_columns(small, big)
    agents = np.arange(n)[:, None]
    out: dict[str, np.ndarray] = {}
    for key in ("obs", "next_obs"):
        x = np.asarray(rows[key], np.float32)
        if x.shape != (t, n, small.obs_dim):
            raise ValueError(f"{key} must be [T={t}, {n}, {small.obs_dim}], got {x.shape}")
        flat = np.concatenate([x, np.zeros_like(x[..., :1])], -1)  # column small.obs_dim reads 0
        out[key] = np.zeros((t, big_n, big.obs_dim), np.float32)
        out[key][:, :n] = flat[:, agents, src]
    for key in ("act", "rew", "done"):
        x = np.asarray(rows[key], np.float32)
        if x.shape[:2] != (t, n):
            raise ValueError(f"{key} must be [T={t}, {n}, ...], got {x.shape}")
        out[key] = np.zeros((t, big_n, *x.shape[2:]), np.float32)
        out[key][:, :n] = x
    out["present"] = np.zeros((t, big_n), bool)
    out["present"][:, :n] = present
    return out

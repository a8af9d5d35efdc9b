"""Episode metrics of the sparse tasks (ALGORITHM.md §6.3), vectorised over B worlds.

Where it sits: called at the final step of an episode by both the PettingZoo envs (B = 1) and the
batched twins, and usable on any saved positions by evaluation code.

* cover matrix: agent i covers landmark l when their centres are closer than `radius` (0.1).
* coverage rate: fraction of landmarks covered by some agent (the paper's landmark cover rate, taken
  at the final step).
* success: every landmark covered by a *distinct* agent, i.e. a perfect matching of landmarks into
  agents in the cover relation (checked with Hall's condition, exact).
* predator win: at least one capture during the episode.
"""

from __future__ import annotations

import functools
import itertools

import numpy as np

_HALL_MAX_LANDMARKS = 12  # 2^12 subsets; beyond that, augmenting paths per world


def cover_matrix(agent_pos: np.ndarray, landmark_pos: np.ndarray, radius: float = 0.1) -> np.ndarray:
    """bool[B, N, L]: agent i within `radius` of landmark l. agent_pos: [B, N, 2], landmark_pos: [B, L, 2]."""
    agent_pos = np.asarray(agent_pos, dtype=np.float64)
    landmark_pos = np.asarray(landmark_pos, dtype=np.float64)
    d = np.sqrt(np.square(landmark_pos[:, None, :, :] - agent_pos[:, :, None, :]).sum(-1))  # [B, N, L]
    return d < radius


def coverage_rate(cover: np.ndarray) -> np.ndarray:
    """float64[B]: fraction of landmarks covered by at least one agent. cover: bool[B, N, L]."""
    cover = np.asarray(cover, dtype=bool)
    if cover.shape[2] == 0:
        return np.ones(cover.shape[0])
    return cover.any(axis=1).mean(axis=1)


@functools.lru_cache(maxsize=16)
def _hall_subsets(num_landmarks: int) -> tuple[np.ndarray, np.ndarray]:
    """All non-empty landmark subsets as bool[S, L] and their sizes int64[S]."""
    rows = [bits for bits in itertools.product((False, True), repeat=num_landmarks) if any(bits)]
    subsets = np.array(rows, dtype=bool).reshape(len(rows), num_landmarks)
    return subsets, subsets.sum(axis=1)


def _matching_size(adj: np.ndarray) -> int:
    """Maximum bipartite matching size (Kuhn's augmenting paths). adj: bool[L, N] landmark-agent edges."""
    num_l, num_a = adj.shape
    match_agent = -np.ones(num_a, dtype=np.int64)

    def augment(l: int, seen: np.ndarray) -> bool:
        for a in np.flatnonzero(adj[l]):
            if not seen[a]:
                seen[a] = True
                if match_agent[a] < 0 or augment(int(match_agent[a]), seen):
                    match_agent[a] = l
                    return True
        return False

    return sum(augment(l, np.zeros(num_a, dtype=bool)) for l in range(num_l))


def success(cover: np.ndarray) -> np.ndarray:
    """bool[B]: all landmarks covered by distinct agents (perfect matching). cover: bool[B, N, L].

    Hall's theorem: a matching saturating every landmark exists iff every landmark subset S is covered
    by at least |S| distinct agents. Exact; vectorised over B for L <= 12.
    """
    cover = np.asarray(cover, dtype=bool)
    b, n, num_l = cover.shape
    if num_l == 0:
        return np.ones(b, dtype=bool)
    if n < num_l:
        return np.zeros(b, dtype=bool)
    if num_l > _HALL_MAX_LANDMARKS or n > 62:
        return np.array([_matching_size(cover[k].T) == num_l for k in range(b)], dtype=bool)
    weights = np.left_shift(np.int64(1), np.arange(n, dtype=np.int64))  # agent i -> bit i
    masks = (cover.astype(np.int64) * weights[None, :, None]).sum(axis=1)  # [B, L] agents covering l
    subsets, sizes = _hall_subsets(num_l)
    unions = np.bitwise_or.reduce(np.where(subsets[None], masks[:, None, :], 0), axis=2)  # [B, S]
    return (np.bitwise_count(unions) >= sizes[None]).all(axis=1)


def predator_win(captures: np.ndarray) -> np.ndarray:
    """bool[B]: the predators win an episode iff at least one capture happened. captures: int[B] counts."""
    return np.asarray(captures) >= 1

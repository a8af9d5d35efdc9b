"""Entity view of the built-in tasks' flat observations: the agent's own features plus typed entities.

Where it sits: the envs keep emitting the flat MPE observation (parity with mpe2; the replay stores it unchanged).
The entity networks (`cmcl.learners.entity.nets`) read it through an :class:`EntityLayout`, which says, for every
agent, which flat columns are its own features and which are each entity's features:

    split(obs float32[..., N, obs_dim]) -> own float32[..., N, S], entities float32[..., N, E, F], mask bool[..., N, E]
    (or the rows of some agents only: split(obs [..., A, obs_dim], agents int64[A]))

An entity row is ``[raw features (P), type one-hot (T)]`` (F = P + T); a raw feature the agent does not observe
(an obstacle's or a predator's velocity in tag) is 0. The mask marks present entities; it is all True for a built-in
world of one size. Rows of several agent counts share one padded buffer (the agent-count curriculum,
`run.carry_replay`, cmcl.replay.agent_padding): a row holding only the first n of the N agents masks, in every
agent's view, the entities that exist only with more agents (`needs_agents`, `present_mask`). The layouts:

  navigation (BatchedSparseSpread, SpreadParams.obs_dim = 4 + 2L + 2(N-1), L = N):
    own [vel(2), pos(2)] (S = 4); entities: L landmarks [landmark_l - pos_i], then N-1 other agents
    [pos_j - pos_i] (j != i, in index order); P = 2, types (landmark, agent), F = 4, E = 2N - 1.
    With SpreadParams.agent_tags (obs_dim + N: [u_i, u_j for j != i] at the end): own [vel, pos, u_i] (S = 5);
    landmarks [landmark_l - pos_i, 0], other agents [pos_j - pos_i, u_j]; P = 3, F = 5.
  predator-prey (BatchedSparseTag, TagParams.obs_dims, m predators then q prey):
    own [vel(2), pos(2), team one-hot (predator, prey)] (S = 6); entities: O obstacles [obstacle_o - pos_i, 0, 0],
    then N-1 other agents [pos_j - pos_i, vel_j if j is prey else (0, 0)]; P = 4, types (obstacle, predator, prey),
    F = 7, E = O + N - 1.
Pure numpy; `split` also takes torch tensors (the index arrays are converted on the fly).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from cmcl.envs.params import SpreadParams, TagParams

__all__ = ["EntityLayout", "entities_present", "entity_layout", "spread_layout", "tag_layout"]

ABSENT = -1  # entity_index value of a raw feature the agent does not observe (read as 0)


def entities_present(mask: Any, needs_agents: Any, count: Any) -> Any:
    """The presence rule, in one place: an entity slot is present when the layout has it (mask bool[..., E]) and
    its row holds at least the agents it needs (needs_agents int64[..., E] <= count int64[...]) -> bool[..., E].
    Numpy or torch alike (EntityLayout.present_mask; the entity critic calls it on its registered buffers)."""
    return mask & (needs_agents <= count[..., None])


@dataclass(frozen=True, eq=False)
class EntityLayout:
    """How each agent's flat observation splits into its own features and E typed entities of F features.

    obs_dim: flat observation width.  type_names: the T entity types, in one-hot order.
    own_index: int64[N, S_obs], the flat columns of each agent's own features.
    own_const: float32[N, S_c], constant own features appended after them (the team one-hot; S_c may be 0).
    entity_index: int64[N, E, P], the flat column of each raw entity feature, ABSENT (-1) for an unobserved one.
    entity_type: float32[N, E, T], each entity's type one-hot.  mask: bool[N, E], present entities.
    entity_agent: int64[N, E], the agent an entity slot shows (-1 for a landmark or an obstacle): what a centralised
        critic adds that agent's own features and action to.
    needs_agents: int64[N, E], the fewest agents a world holds for the entity to exist (an entity showing agent j:
        j + 1; navigation's landmark l: l + 1, since L = N; an obstacle: 0). None: 0 for landmarks and obstacles,
        j + 1 for agents. Rows of n present agents (the first n; cmcl.replay.agent_padding) see entity e iff
        needs_agents[i, e] <= n.
    """

    obs_dim: int
    type_names: tuple[str, ...]
    own_index: np.ndarray
    own_const: np.ndarray
    entity_index: np.ndarray
    entity_type: np.ndarray
    mask: np.ndarray
    entity_agent: np.ndarray
    needs_agents: np.ndarray | None = None

    def __post_init__(self) -> None:
        n, e, _ = self.entity_index.shape
        if self.needs_agents is None:
            object.__setattr__(self, "needs_agents", np.where(self.entity_agent >= 0, self.entity_agent + 1, 0))
        if np.shape(self.needs_agents) != (n, e):
            raise ValueError("entity layout needs_agents disagrees on the agent / entity counts")
        if self.own_index.shape[0] != n or self.own_const.shape[0] != n or self.entity_type.shape[:2] != (n, e) \
                or self.mask.shape != (n, e) or self.entity_type.shape[2] != len(self.type_names) \
                or self.entity_agent.shape != (n, e):
            raise ValueError("entity layout arrays disagree on the agent / entity / type counts")
        used = np.concatenate([self.own_index.ravel(), self.entity_index.ravel()])
        if used.size and (used.min() < ABSENT or used.max() >= self.obs_dim):
            raise ValueError(f"entity layout indexes columns outside [0, obs_dim={self.obs_dim})")

    @property
    def num_agents(self) -> int:
        return int(self.entity_index.shape[0])

    @property
    def num_entities(self) -> int:
        """E, entity slots per agent."""
        return int(self.entity_index.shape[1])

    @property
    def own_dim(self) -> int:
        """S, own features per agent."""
        return int(self.own_index.shape[1] + self.own_const.shape[1])

    @property
    def entity_dim(self) -> int:
        """F = P raw features + T type one-hot."""
        return int(self.entity_index.shape[2] + self.entity_type.shape[2])

    def present_mask(self, count: Any, agents: Any = None) -> Any:
        """Entities present in rows of `count` present agents (the first ones): count int64[..., A] (numpy or torch),
        the present agents of agent agents[a]'s row (default: all N agents) -> bool[..., A, E] = mask &
        (needs_agents <= count)."""
        agents = np.arange(self.num_agents) if agents is None else np.asarray(agents, np.int64)
        xp = _namespace(count)
        return entities_present(xp.const(self.mask[agents], count), xp.const(self.needs_agents[agents], count), count)

    def split(self, obs: Any, agents: Any = None) -> tuple[Any, Any, Any]:
        """obs float32[..., A, obs_dim] (numpy or torch), row a being agent agents[a]'s observation (default: all
        N agents in order) -> own [..., A, S], entities [..., A, E, F], mask [..., A, E] (same library as obs)."""
        agents = np.arange(self.num_agents) if agents is None else np.asarray(agents, np.int64)
        if obs.shape[-2:] != (len(agents), self.obs_dim):
            raise ValueError(f"obs must be [..., A={len(agents)}, obs_dim={self.obs_dim}], got {tuple(obs.shape)}")
        xp = _namespace(obs)
        lead, a = tuple(obs.shape[:-2]), len(agents)
        padded = xp.cat([obs, xp.zeros_like(obs[..., :1])], -1)  # column obs_dim is 0: ABSENT reads it
        cols = np.where(self.entity_index == ABSENT, self.obs_dim, self.entity_index)[agents]  # [A, E, P]
        raw = padded[..., xp.index(np.broadcast_to(np.arange(a).reshape(a, 1, 1), cols.shape)), xp.index(cols)]
        types = self.entity_type[agents]
        ents = xp.cat([raw, xp.expand(xp.const(types, obs), (*lead, *types.shape))], -1)
        own_cols = self.own_index[agents]
        own = obs[..., xp.index(np.broadcast_to(np.arange(a)[:, None], own_cols.shape)), xp.index(own_cols)]
        const = self.own_const[agents]
        own = xp.cat([own, xp.expand(xp.const(const, obs), (*lead, *const.shape))], -1)
        mask = self.mask[agents]
        return own, ents, xp.expand(xp.const(mask, obs), (*lead, *mask.shape))


class _Numpy:
    cat = staticmethod(lambda xs, axis: np.concatenate(xs, axis))
    zeros_like = staticmethod(np.zeros_like)
    index = staticmethod(lambda a: a)
    const = staticmethod(lambda a, like: a.astype(like.dtype) if a.dtype != bool else a)
    expand = staticmethod(np.broadcast_to)


class _Torch:
    def __init__(self, torch: Any):
        self.t = torch

    def cat(self, xs, axis):
        return self.t.cat(xs, axis)

    def zeros_like(self, x):
        return self.t.zeros_like(x)

    def index(self, a):
        return self.t.from_numpy(np.ascontiguousarray(a, dtype=np.int64))

    def const(self, a, like):
        t = self.t.from_numpy(np.ascontiguousarray(a))
        return t if a.dtype == bool else t.to(like.dtype)

    def expand(self, x, shape):
        return x.expand(*shape)


def _namespace(x: Any) -> Any:
    if isinstance(x, np.ndarray):
        return _Numpy
    import torch  # only when given a tensor: the numpy path never loads torch

    return _Torch(torch)


def spread_layout(num_agents: int, agent_tags: bool = False) -> EntityLayout:
    """Navigation's layout for N agents and L = N landmarks, with or without the agent tags (SpreadParams.agent_tags;
    module docstring)."""
    n = int(num_agents)
    num_l, others = n, n - 1
    params = SpreadParams(num_agents=n, agent_tags=agent_tags)
    lm = 4 + 2 * np.arange(num_l)[:, None] + np.arange(2)  # [L, 2]
    oth = 4 + 2 * num_l + 2 * np.arange(others)[:, None] + np.arange(2)  # [N-1, 2]
    own = np.arange(4)
    if params.agent_tags:  # own tag after [vel, pos]; the k-th other agent's tag after its [dx, dy]
        lm = np.concatenate([lm, np.full((num_l, 1), ABSENT)], 1)
        oth = np.concatenate([oth, params.tags_at + 1 + np.arange(others)[:, None]], 1)
        own = np.r_[own, params.tags_at]
    index = np.broadcast_to(np.concatenate([lm, oth])[None], (n, num_l + others, lm.shape[1])).copy()
    kind = np.r_[np.zeros(num_l, np.int64), np.ones(others, np.int64)]
    types = np.broadcast_to(np.eye(2, dtype=np.float32)[kind][None], (n, num_l + others, 2)).copy()
    shown = np.array([[-1] * num_l + [j for j in range(n) if j != i] for i in range(n)], np.int64).reshape(n, -1)
    needs = np.where(shown >= 0, shown + 1, np.arange(num_l + others) + 1)  # landmark l exists from l + 1 agents
    return EntityLayout(params.obs_dim, ("landmark", "agent"), np.broadcast_to(own, (n, len(own))).copy(),
                        np.zeros((n, 0), np.float32), index, types, np.ones((n, num_l + others), bool), shown, needs)


def tag_layout(params: TagParams) -> EntityLayout:
    """Predator-prey's layout (module docstring): predators are agents 0..m-1, prey m..N-1."""
    m, q, o, n = params.num_predators, params.num_prey, params.num_obstacles, params.num_agents
    off_a, off_v = 4 + 2 * o, 4 + 2 * o + 2 * (n - 1)
    e = o + n - 1
    index = np.full((n, e, 4), ABSENT, np.int64)
    kind = np.zeros((n, e), np.int64)  # 0 obstacle, 1 predator, 2 prey
    shown = np.full((n, e), -1, np.int64)
    index[:, :o, :2] = 4 + 2 * np.arange(o)[:, None] + np.arange(2)
    for i in range(n):  # layout construction only, once per run
        other_prey = [p for p in range(q) if p != i - m]  # a prey's velocity block lists the other prey only
        for k, j in enumerate(jj for jj in range(n) if jj != i):
            index[i, o + k, :2] = off_a + 2 * k + np.arange(2)
            kind[i, o + k], shown[i, o + k] = (1 if j < m else 2), j
            if j >= m:
                slot = j - m if i < m else other_prey.index(j - m)
                index[i, o + k, 2:] = off_v + 2 * slot + np.arange(2)
    team = np.zeros((n, 2), np.float32)
    team[:m, 0], team[m:, 1] = 1.0, 1.0
    obs_dim = max(params.obs_dims)
    return EntityLayout(obs_dim, ("obstacle", "predator", "prey"), np.broadcast_to(np.arange(4), (n, 4)).copy(),
                        team, index, np.eye(3, dtype=np.float32)[kind], np.ones((n, e), bool), shown)


def entity_layout(params: Any) -> EntityLayout | None:
    """The layout of a built-in world (SpreadParams or TagParams), None for anything else (a factory env)."""
    if isinstance(params, SpreadParams):
        return spread_layout(params.num_agents, params.agent_tags)
    if isinstance(params, TagParams):
        return tag_layout(params)
    return None

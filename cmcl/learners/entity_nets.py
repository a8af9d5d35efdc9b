"""Entity networks: one actor and one centralised critic for all agents, whose parameter count does not depend on N.

Where it sits: ``maddpg.networks = "entity"`` (cmcl.config) makes :class:`cmcl.learners.maddpg.MADDPG` build these
instead of per-agent ``StackedMLP``s; they take the same flat inputs and give the same shapes, so the update, the
targets, the teachers' targets and the checkpoints run unchanged. The flat observation is read through an
:class:`cmcl.envs.entities.EntityLayout` (own features S, E entities of F features, a mask).

  encoder   (EPC-style, Long et al. 2020): own -> s = relu(W_s own) [H]; every entity -> h_e = relu(W_e x_e) [H]
            (one weight for all entities and agents); one-head attention from the agent's own embedding,
            α = softmax_e(h_e · W_q s / √H) over present entities, and a masked max pool:
            z = [s, Σ_e α_e h_e, max_e h_e]  float32[..., 3H].
  actor     π(o_i) = head(z_i), head an MLP 3H -> H -> act_dim (tanh, or logits when discrete).
  critic    (PIC-style, Liu et al. 2019): every agent j's u_j = φ([z_j, a_j]) [H] with one shared φ; one graph
            convolution over the complete agent graph g_j = relu(W_1 u_j + W_2 mean_k u_k); then
            Q_i = ψ([g_i, max_k g_k]) for every agent i in one pass: float32[..., N]. Permuting the agents permutes
            the Q's; permuting agent i's landmarks or other agents within its observation leaves z_i unchanged.

Every layer is a :class:`~cmcl.learners.nets.StackedLinear` with a leading *group* axis G of independent networks:
G = 1 for the learner, G = K for the K-fold teachers (one network per fold, so a fold's network never sees another
fold's rows). Cost per row: O(N·E·F·H) for the entity layer, O(N·H²) for the rest; no Python loop over agents
or entities.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from cmcl.envs.entities import EntityLayout
from cmcl.learners.nets import StackedLinear, StackedMLP

__all__ = ["EntityActor", "EntityCritic", "EntityEncoder"]


class EntityEncoder(nn.Module):
    """z = [s, attention pool, max pool] of each (own, entities, mask) row, G independent groups (module docstring).

    own float32[G, R, S], entities float32[G, R, E, F], mask bool[G, R, E] -> z float32[G, R, 3H].
    """

    def __init__(self, groups: int, own_dim: int, entity_dim: int, hidden: int, generator: torch.Generator):
        super().__init__()
        self.hidden = int(hidden)
        self.own = StackedLinear(groups, own_dim, hidden, generator)
        self.entity = StackedLinear(groups, entity_dim, hidden, generator)
        self.query = StackedLinear(groups, hidden, hidden, generator)

    @property
    def out_dim(self) -> int:
        return 3 * self.hidden

    def forward(self, own: torch.Tensor, entities: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        g, r, e, f = entities.shape
        s = torch.relu(self.own(own))  # [G, R, H]
        h = torch.relu(self.entity(entities.reshape(g, r * e, f))).view(g, r, e, self.hidden)  # [G, R, E, H]
        q = self.query(s) / math.sqrt(self.hidden)  # [G, R, H]
        logits = torch.matmul(h, q.unsqueeze(-1)).squeeze(-1).masked_fill(~mask, float("-inf"))  # [G, R, E]
        alpha = torch.softmax(logits, dim=-1).nan_to_num(0.0)  # a row without entities attends to nothing
        pooled = torch.matmul(alpha.unsqueeze(-2), h).squeeze(-2)  # [G, R, H]
        top = h.masked_fill(~mask.unsqueeze(-1), 0.0).amax(-2) if e else torch.zeros_like(s)  # h >= 0: 0 is neutral
        return torch.cat([s, pooled, top], -1)


def _grouped_split(layout: EntityLayout, obs: torch.Tensor, groups: int) -> tuple[torch.Tensor, ...]:
    """obs float32[G, ..., N, obs_dim] -> own [G, R, S], entities [G, R, E, F], mask [G, R, E] (R = rows·N)."""
    own, ents, mask = layout.split(obs)
    return (own.reshape(groups, -1, own.shape[-1]), ents.reshape(groups, -1, *ents.shape[-2:]),
            mask.reshape(groups, -1, mask.shape[-1]))


class EntityActor(nn.Module):
    """One actor for all agents: float32[N, B, obs_dim] (agent axis first, as StackedMLP) -> float32[N, B, act_dim].

    ``members`` is accepted for StackedMLP's signature and must be None (every agent acts from its own row).
    """

    def __init__(self, layout: EntityLayout, act_dim: int, hidden: int, generator: torch.Generator,
                 out_act: type[nn.Module] | None = None):
        super().__init__()
        self.layout, self.num_agents, self.act_dim = layout, layout.num_agents, int(act_dim)
        self.encoder = EntityEncoder(1, layout.own_dim, layout.entity_dim, hidden, generator)
        self.head = StackedMLP(1, self.encoder.out_dim, (hidden,), act_dim, out_act=out_act, generator=generator)

    def forward(self, x: torch.Tensor, members: torch.Tensor | None = None) -> torch.Tensor:
        if members is not None or x.shape[0] != self.num_agents:
            raise ValueError(f"the entity actor takes every agent's rows [N={self.num_agents}, B, obs_dim], "
                             f"got {tuple(x.shape)} (members={members})")
        obs = x.transpose(0, 1).unsqueeze(0)  # [1, B, N, obs_dim]
        z = self.encoder(*_grouped_split(self.layout, obs, 1))  # [1, B*N, 3H]
        return self.head(z).view(x.shape[1], self.num_agents, self.act_dim).transpose(0, 1)


class EntityCritic(nn.Module):
    """Q_i for every agent i from all agents' observations and actions, G independent groups (module docstring).

    :meth:`q_all`: obs float32[G, M, N, obs_dim], act float32[G, M, N, act_dim] -> Q float32[G, M, N].
    :meth:`forward` is StackedMLP's critic signature on the joint input (nets.joint_input, [..., N·obs_dim +
    N·act_dim]), for G = 1: shared rows [M, in] -> [N (or len(members)), M, 1]; per-owner rows [N', S, in]
    -> [N', S, 1], row v scored by agent members[v] (default v), each from one pass over all agents.
    """

    def __init__(self, layout: EntityLayout, act_dim: int, hidden: int, generator: torch.Generator,
                 groups: int = 1):
        super().__init__()
        self.layout, self.num_agents, self.act_dim, self.groups = layout, layout.num_agents, int(act_dim), int(groups)
        self.obs_dim = layout.obs_dim
        self.encoder = EntityEncoder(groups, layout.own_dim, layout.entity_dim, hidden, generator)
        self.embed = StackedMLP(groups, self.encoder.out_dim + act_dim, (), hidden, out_act=nn.ReLU,
                                generator=generator)
        self.own_conv = StackedLinear(groups, hidden, hidden, generator)
        self.mean_conv = StackedLinear(groups, hidden, hidden, generator)
        self.value = StackedMLP(groups, 2 * hidden, (hidden,), 1, generator=generator)

    def q_all(self, obs: torch.Tensor, act: torch.Tensor) -> torch.Tensor:
        g, m, n, _ = obs.shape
        z = self.encoder(*_grouped_split(self.layout, obs, g))  # [G, M*N, 3H]
        u = self.embed(torch.cat([z, act.reshape(g, m * n, -1)], -1))  # [G, M*N, H]
        conv_in = u.view(g, m, n, -1).mean(2, keepdim=True).expand(g, m, n, -1).reshape(g, m * n, -1)
        gc = torch.relu(self.own_conv(u) + self.mean_conv(conv_in)).view(g, m, n, -1)  # [G, M, N, H]
        pool = gc.amax(2, keepdim=True).expand_as(gc)
        return self.value(torch.cat([gc, pool], -1).view(g, m * n, -1)).view(g, m, n)

    def joint_q(self, x: torch.Tensor) -> torch.Tensor:
        """Joint inputs float32[G, M, N·obs_dim + N·act_dim] -> Q float32[G, M, N]."""
        n, split = self.num_agents, self.num_agents * self.obs_dim
        obs = x[..., :split].unflatten(-1, (n, self.obs_dim))
        act = x[..., split:].unflatten(-1, (n, self.act_dim))
        return self.q_all(obs, act)

    def forward(self, x: torch.Tensor, members: torch.Tensor | None = None) -> torch.Tensor:
        if self.groups != 1:
            raise ValueError("forward is the learner's signature (one group); use joint_q for grouped critics")
        agents = torch.arange(self.num_agents) if members is None else members
        if x.dim() == 3 and x.stride(0) == 0:  # the same rows for every critic (expanded): score them once
            x = x[0]
        if x.dim() == 2:  # shared rows [M, in]
            return self.joint_q(x.unsqueeze(0))[0].T[agents].unsqueeze(-1)  # [A, M, 1]
        owners, s = x.shape[0], x.shape[1]
        if owners != len(agents):
            raise ValueError(f"per-owner rows {tuple(x.shape)} need one agent per owner, got {len(agents)}")
        q = self.joint_q(x.reshape(1, owners * s, -1)).view(owners, s, self.num_agents)  # [owners, S, N]
        return q.gather(2, agents.view(owners, 1, 1).expand(owners, s, 1))  # owner v's own Q: [owners, S, 1]

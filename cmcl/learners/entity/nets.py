"""Entity networks: one actor and one centralised critic for all agents, whose parameter count does not depend on N.

Where it sits: ``maddpg.networks = "entity"`` (cmcl.config) makes :class:`cmcl.learners.maddpg.MADDPG` build these
instead of per-agent ``StackedMLP``s; they take the same flat inputs and give the same shapes, so the update, the
targets, the teachers' targets and the checkpoints run unchanged. The flat observation is read through an
:class:`cmcl.envs.entities.EntityLayout` (own features S, E entities of F features, a mask).

  encoder  (attention over entities, as EPC, Long et al. 2020): own -> s = relu(W_s own) [H]; every entity
           -> h_e = relu(W_e x_e) [H] (one weight for all entities and agents); one-head attention from the own
           embedding, α = softmax_e(h_e · (W_q s + b_q) / √H) over the present entities, and a masked mean:
           z = [s, Σ_e α_e h_e, mean_e h_e]  float32[..., 3H].
  actor    π(o_i) = head(z_i), head an MLP 3H -> H -> act_dim (tanh, or logits when discrete).
  critic   Q_i(s, a) = value(z_i^c), z_i^c the encoder (its own weights) on agent i's view augmented with what a
           centralised critic knows: own [own_i, a_i]; entity slot e showing agent j: [x_e, own_j, a_j]
           (landmarks / obstacles: [x_e, 0, 0]). Agent i's own view already holds the relative position of every
           other agent and landmark, so this is the full state and joint action, seen from i, pooled symmetrically
           over the other agents (the permutation invariance of PIC, Liu et al. 2019, whose graph critic embeds
           every agent's whole observation instead: N·E entity rows per Q against E here; built that way, with an
           encoder since made about twice as fast, an update at N = 8 took ~1.4 s on one core).
           Permuting the agents permutes the Q's; permuting agent i's landmarks or other agents leaves Q_i as it is.

Every layer is a :class:`~cmcl.learners.nets.StackedLinear` with a leading *group* axis G of independent networks:
G = 1 for the learner, G = K for the K-fold teachers (one network per fold, so a fold's network never sees another
fold's rows). No Python loop over agents or entities.

Rows carried from fewer agents (run.carry_replay; cmcl.replay.agent_padding): the actor and the critic take an
optional ``count`` (int64, the present agents of each row, always the first ones) and mask, in every agent's view,
the entities that exist only with more agents (EntityLayout.present_mask): an absent agent's entity slot, its
observation and its action never reach a present agent's embedding or Q.

Opt-ins (cmcl.learners.entity.picks: which entity rows a network reads): ``nearest`` = k > 0 keeps the k nearest
present entities of each kind (:func:`nearest_entities`, maddpg.entity_nearest); ``holder`` appends every entity
row's holder margin, computed before that pick (:func:`holder_margin`, cmcl.learners.entity.holder; navigation only,
maddpg.entity_holder): one more entity input; ``holder_rule`` which other agents hold a landmark (maddpg.holder_rule,
"nearest" or "seated").
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from cmcl.envs.entities import EntityLayout
from cmcl.learners.entity.holder import holder_margin
from cmcl.learners.entity.ops import dense, mlp
from cmcl.learners.entity.picks import EntityOptIns, nearest_entities
from cmcl.learners.entity.views import CriticViews
from cmcl.learners.nets import StackedLinear, StackedMLP

__all__ = ["POOLS", "EntityActor", "EntityCritic", "EntityEncoder", "EntityFeatures", "holder_margin",
           "nearest_entities"]

# the encoder's pooling over entities (maddpg.entity_pool); "relational" is "attention" after one round of
# self-attention among the entities (EntityEncoder)
POOLS = ("attention", "mean", "relational")
RELATION_DIM = 16  # query / key width of the relational round


def masked_softmax(logits: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    """Softmax over the last axis of `logits` where `mask` (broadcast against it; None: everywhere) holds, 0 elsewhere;
    a row with nothing present gets all 0 (it attends to nothing)."""
    if mask is not None:
        logits = logits.masked_fill(~mask, float("-inf"))
    return torch.softmax(logits, -1).nan_to_num(0.0)


class EntityEncoder(nn.Module):
    """z = [s, attention pool, mean pool] of each (own, entities, mask) row, G groups (module docstring); with
    pool="mean" z = [s, mean pool] (no attention: ~2x cheaper per entity, DeepSets-style).

    pool="relational" first lets every entity attend to the present entities (one head, queries and keys of
    RELATION_DIM): h_e <- h_e + relu(W_r Σ_e' β_ee' h_e'), β_e = softmax_e'(W_a h_e · W_b h_e' / √RELATION_DIM).
    An entity's embedding then carries what is near it (a landmark, that another agent already sits on it), a
    relation between two entities that pooling from the agent's own embedding cannot form: with the plain
    attention pool, shared actors at N = 8 left half their agents on a landmark another agent also held.

    own float32[G, R, S], entities float32[G, R, E, F], mask bool[G, R, E] -> z float32[G, R, 3H] (or 2H).

    ``fused`` (True): the layers of one group run as fused GEMM + bias + ReLU kernels (cmcl.learners.entity.ops.dense)
    and an entity critic gathers its inputs with CriticViews.gather; False: the reference ops (StackedLinear, the
    advanced-indexing views), the same numbers to float32's last bits (bench/entity_cost.py times both).
    """

    fused = True

    def __init__(self, groups: int, own_dim: int, entity_dim: int, hidden: int, generator: torch.Generator,
                 pool: str = "attention"):
        super().__init__()
        if pool not in POOLS:
            raise ValueError(f"pool must be one of {list(POOLS)}, got {pool!r}")
        self.hidden, self.pool = int(hidden), pool
        self.own = StackedLinear(groups, own_dim, hidden, generator)
        self.entity = StackedLinear(groups, entity_dim, hidden, generator)
        if pool != "mean":
            self.query = StackedLinear(groups, hidden, hidden, generator)
        if pool == "relational":
            self.relate_query = StackedLinear(groups, hidden, RELATION_DIM, generator)
            self.relate_key = StackedLinear(groups, hidden, RELATION_DIM, generator)
            self.relate_out = StackedLinear(groups, hidden, hidden, generator)

    @property
    def out_dim(self) -> int:
        return (2 if self.pool == "mean" else 3) * self.hidden

    def layer(self, layer: StackedLinear, x: torch.Tensor, relu: bool = False) -> torch.Tensor:
        """One of this encoder's layers (then ReLU): x float32[G, R, in] -> float32[G, R, out]; fused kernels
        (entity_ops.dense) unless ``fused`` is False."""
        if self.fused:
            return dense(layer, x, relu)
        out = layer(x)
        return out.relu_() if relu else out  # in place: torch.relu on a fresh tensor runs ~5x slower here

    def relate(self, h: torch.Tensor, mask: torch.Tensor, everyone: bool) -> torch.Tensor:
        """One round of masked self-attention among the entities: h float32[G, R, E, H] -> the same shape."""
        g, r, e, hid = h.shape
        flat = h.reshape(g, r * e, hid)
        q = self.layer(self.relate_query, flat).view(g * r, e, RELATION_DIM)
        k = self.layer(self.relate_key, flat).view(g * r, e, RELATION_DIM)
        logits = torch.bmm(q, k.transpose(1, 2)) / math.sqrt(RELATION_DIM)  # [GR, E (query), E (key)]
        beta = masked_softmax(logits, None if everyone else mask.reshape(g * r, 1, e))
        context = torch.bmm(beta, flat.view(g * r, e, hid)).view(g, r * e, hid)
        return h + self.layer(self.relate_out, context, True).view(g, r, e, hid)

    def forward(self, own: torch.Tensor, entities: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return self.encode(own, entities, mask)[0]

    def encode(self, own: torch.Tensor, entities: torch.Tensor, mask: torch.Tensor
               ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """z as `forward` gives it, and the attention pool's logits over the entity slots float32[G, R, E]
        (h_e · q / √H, before the mask and the softmax; None with pool="mean" or no entity slot)."""
        g, r, e, f = entities.shape
        s = self.layer(self.own, own, True)  # [G, R, H]
        if e == 0:
            return torch.cat([s, *[torch.zeros_like(s)] * (self.out_dim // self.hidden - 1)], -1), None
        h = self.layer(self.entity, entities.reshape(g, r * e, f), True).view(g, r, e, self.hidden)  # [G, R, E, H]
        everyone = bool(mask.all())
        if self.pool == "relational":
            h = self.relate(h, mask, everyone)
        if everyone:
            mean = h.mean(-2)
        else:
            weight = mask.to(h.dtype)
            mean = (h * weight.unsqueeze(-1)).sum(-2) / weight.sum(-1, keepdim=True).clamp(min=1.0)
        if self.pool == "mean":
            return torch.cat([s, mean], -1), None
        q = self.layer(self.query, s) / math.sqrt(self.hidden)  # [G, R, H]
        logits = torch.einsum("greh,grh->gre", h, q)  # [G, R, E]
        alpha = masked_softmax(logits, None if everyone else mask)  # [G, R, E]
        pooled = torch.einsum("gre,greh->grh", alpha, h)  # [G, R, H]
        return torch.cat([s, pooled, mean], -1), logits


class EntityActor(EntityOptIns, nn.Module):
    """One actor for all agents: float32[N, B, obs_dim] (agent axis first, as StackedMLP) -> float32[N, B, act_dim].

    ``members`` is accepted for StackedMLP's signature and must be None (every agent acts from its own row).
    ``count`` int64[N, B]: the present agents of agent i's row b (None: all N; module docstring).
    ``holder``: every entity row gets its holder margin, F + 1 entity features (module docstring).
    """

    def __init__(self, layout: EntityLayout, act_dim: int, hidden: int, generator: torch.Generator,
                 out_act: type[nn.Module] | None = None, pool: str = "attention", nearest: int = 0,
                 holder: bool = False, holder_rule: str = "nearest"):
        super().__init__()
        self.layout, self.num_agents, self.act_dim = layout, layout.num_agents, int(act_dim)
        self._set_opt_ins(layout, nearest, holder, holder_rule)
        self.encoder = EntityEncoder(1, layout.own_dim, layout.entity_dim + self.holder, hidden, generator, pool)
        self.head = StackedMLP(1, self.encoder.out_dim, (hidden,), act_dim, out_act=out_act, generator=generator)

    def forward(self, x: torch.Tensor, members: torch.Tensor | None = None,
                count: torch.Tensor | None = None) -> torch.Tensor:
        return self.act_and_attend(x, members, count)[0]

    def act_and_attend(self, x: torch.Tensor, members: torch.Tensor | None = None, count: torch.Tensor | None = None
                       ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """`forward`'s output float32[N, B, act_dim] and, from the same pass, the attention pool's logits over
        agent i's entity slots float32[N, B, E] (EntityEncoder.encode: before the mask and softmax; None with
        pool="mean"; with `nearest` the slots are the picked ones). The landmark-assignment loss reads them
        (cmcl.learners.entity.assignment)."""
        if members is not None or x.shape[0] != self.num_agents:
            raise ValueError(f"the entity actor takes every agent's rows [N={self.num_agents}, B, obs_dim], "
                             f"got {tuple(x.shape)} (members={members})")
        own, ents, mask = self.layout.split(x.transpose(0, 1))  # [B, N, S], [B, N, E, F], [B, N, E]
        if count is not None:
            mask = self.layout.present_mask(count.transpose(0, 1))
        ents, mask = self._opt_ins(ents, mask)
        z, logits = self.encoder.encode(own.flatten(0, 1)[None], ents.flatten(0, 1)[None], mask.flatten(0, 1)[None])
        b, n = x.shape[1], self.num_agents
        out = mlp(self.head, z, self.encoder.fused).view(b, n, self.act_dim).transpose(0, 1)
        return out, None if logits is None else logits.view(b, n, -1).transpose(0, 1)


class EntityFeatures(EntityOptIns, nn.Module):
    """One observation encoder for some agents (the ICM's φ, eq. 13): float32[A, M, obs_dim], row a being agent
    agents[a]'s observations -> float32[A, M, out_dim] = W·z + b, z the entity encoder's output; with `nearest` = k > 0
    over the k nearest entities of each kind only (nearest_entities), and with `holder` each entity row with its
    holder margin (holder_margin), as the entity actor reads them."""

    def __init__(self, layout: EntityLayout, agents: list[int], hidden: int, out_dim: int,
                 generator: torch.Generator, pool: str = "attention", nearest: int = 0, holder: bool = False,
                 holder_rule: str = "nearest"):
        super().__init__()
        self.layout, self.agents, self.out_dim = layout, [int(a) for a in agents], int(out_dim)
        self._set_opt_ins(layout, nearest, holder, holder_rule)
        self.encoder = EntityEncoder(1, layout.own_dim, layout.entity_dim + self.holder, hidden, generator, pool)
        self.out = StackedLinear(1, self.encoder.out_dim, out_dim, generator)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        own, ents, mask = self.layout.split(x.transpose(0, 1), self.agents)  # [M, A, S], [M, A, E, F], [M, A, E]
        ents, mask = self._opt_ins(ents, mask)
        z = self.encoder(own.flatten(0, 1)[None], ents.flatten(0, 1)[None], mask.flatten(0, 1)[None])
        return self.encoder.layer(self.out, z).view(x.shape[1], x.shape[0], self.out_dim).transpose(0, 1)


class EntityCritic(EntityOptIns, nn.Module):
    """Centralised Q_i of agent i on each row, G independent groups (module docstring).

    :meth:`q_agent`: obs float32[G, R, N, obs_dim], act float32[G, R, N, act_dim], agent int64[G, R]
    -> Q float32[G, R], the Q of agent agent[g, r] on row r.
    :meth:`q_own_action`: MADDPG's actor step, per-owner rows with the owner's own action replaced (G = 1).
    :meth:`forward` is StackedMLP's critic signature on the joint input (nets.joint_input, [..., N·obs_dim +
    N·act_dim]), for G = 1: shared rows [M, in] -> [A, M, 1] (A = len(members), default N); per-owner rows
    [N', S, in] -> [N', S, 1], owner v's rows scored by agent members[v] (default v).
    Each takes an optional ``count``, the present agents of each row (int64 [G, R]; [M] or [N', S] for forward;
    None: all N; module docstring). ``holder``: every entity row ends with its holder margin, after the shown
    agent's own features and action (F + S + A + 1 entity features).
    """

    def __init__(self, layout: EntityLayout, act_dim: int, hidden: int, generator: torch.Generator,
                 groups: int = 1, pool: str = "attention", nearest: int = 0, holder: bool = False,
                 holder_rule: str = "nearest"):
        super().__init__()
        self.layout, self.num_agents, self.act_dim, self.groups = layout, layout.num_agents, int(act_dim), int(groups)
        self._set_opt_ins(layout, nearest, holder, holder_rule)
        self.obs_dim = layout.obs_dim
        own_in = layout.own_dim + act_dim  # the entity rows: F features, the shown agent's own_in, the margin
        self.encoder = EntityEncoder(groups, own_in, layout.entity_dim + own_in + self.holder, hidden, generator, pool)
        self.value = StackedMLP(groups, self.encoder.out_dim, (hidden,), 1, generator=generator)
        self.views = CriticViews(layout, act_dim)  # the gathers of q_agent (index tables only)
        shown, n = layout.entity_agent, layout.num_agents
        self._sees_itself = bool((shown == np.arange(n)[:, None]).any())  # a slot of agent i showing i

    def q_agent(self, obs: torch.Tensor, act: torch.Tensor, agent: torch.Tensor,
                count: torch.Tensor | None = None) -> torch.Tensor:
        g, r = obs.shape[:2]
        return mlp(self.value, self.encoder(*self._views(obs, act, agent, count)), self.encoder.fused).view(g, r)

    def q_own_action(self, obs: torch.Tensor, act: torch.Tensor, own_act: torch.Tensor,
                     count: torch.Tensor | None = None) -> torch.Tensor:
        """MADDPG's actor step (eq. 4) on per-owner rows, owner v scored by agent v with its own action replaced:
        obs float32[N, S, N, obs_dim], act float32[N, S, N, act_dim] (the buffer's), own_act float32[N, S, act_dim]
        (count int64[N, S] or None) -> Q float32[N, S], the same numbers as :meth:`forward` on the joint input with
        act[v, :, v] replaced by own_act[v].

        Agent v's entity slots show only the other agents (``_sees_itself`` False for every built-in layout), so
        own_act enters Q_v through the own features alone: the entity slots are built from the buffer's actions,
        and the backward pass to own_act skips the entity embeddings (the costly [S, E, H] part), whose gradient
        with respect to own_act is exactly 0 on the joint path.
        """
        n, s = obs.shape[:2]
        if n != self.num_agents:
            raise ValueError(f"q_own_action takes one owner per agent [N={self.num_agents}, S, ...], got {n}")
        rows = (1, n * s)
        agent = torch.arange(n).repeat_interleave(s).view(rows)
        count = None if count is None else count.reshape(rows)
        if self._sees_itself:  # a layout whose slots show the agent itself: the joint path
            own = torch.eye(n, dtype=torch.bool).view(n, 1, n, 1)
            act = torch.where(own, own_act.unsqueeze(2), act)
            return self.q_agent(obs.reshape(*rows, *obs.shape[2:]), act.reshape(*rows, *act.shape[2:]), agent,
                                count).view(n, s)
        own, ents, mask = self._views(obs.reshape(*rows, *obs.shape[2:]), act.reshape(*rows, *act.shape[2:]),
                                      agent, count)
        own = torch.cat([own[..., :-self.act_dim], own_act.reshape(*rows, self.act_dim)], -1)
        return mlp(self.value, self.encoder(own, ents, mask), self.encoder.fused).view(n, s)

    def _views(self, obs: torch.Tensor, act: torch.Tensor, agent: torch.Tensor, count: torch.Tensor | None
               ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The encoder's inputs of q_agent: own float32[G, R, S + A], entities float32[G, R, E, F + S + A (+ 1, the
        holder margin)], mask bool[G, R, E]."""
        views = self.views.gather if self.encoder.fused else self.views.reference
        own, ents, mask = views(obs, act, agent, count)
        ents, mask = self._opt_ins(ents, mask)  # the same holder column whichever view built the rows
        return own, ents, mask

    def forward(self, x: torch.Tensor, members: torch.Tensor | None = None,
                count: torch.Tensor | None = None) -> torch.Tensor:
        if self.groups != 1:
            raise ValueError("forward is the learner's signature (one group); use q_agent for grouped critics")
        agents = torch.arange(self.num_agents) if members is None else members
        if x.dim() == 3 and x.stride(0) == 0:  # the same rows for every critic (expanded): shared rows
            x = x[0]
        if x.dim() == 2:  # shared rows [M, in]: each selected agent scores every row
            m = x.shape[0]
            q = self.joint_q(x.unsqueeze(0).expand(len(agents), m, -1).reshape(1, len(agents) * m, -1),
                             agents.repeat_interleave(m).unsqueeze(0),
                             None if count is None else count.repeat(len(agents)).unsqueeze(0))
            return q.view(len(agents), m, 1)
        owners, s = x.shape[0], x.shape[1]
        if owners != len(agents):
            raise ValueError(f"per-owner rows {tuple(x.shape)} need one agent per owner, got {len(agents)}")
        q = self.joint_q(x.reshape(1, owners * s, -1), agents.repeat_interleave(s).unsqueeze(0),
                         None if count is None else count.reshape(1, owners * s))
        return q.view(owners, s, 1)

    def joint_q(self, x: torch.Tensor, agent: torch.Tensor, count: torch.Tensor | None = None) -> torch.Tensor:
        """Joint inputs float32[G, R, N·obs_dim + N·act_dim], agent int64[G, R] (count int64[G, R] or None)
        -> Q float32[G, R]."""
        n, split = self.num_agents, self.num_agents * self.obs_dim
        obs = x[..., :split].unflatten(-1, (n, self.obs_dim))
        act = x[..., split:].unflatten(-1, (n, self.act_dim))
        return self.q_agent(obs, act, agent, count)


"""Which actor and critic a learner builds (maddpg.networks): per-agent or shared StackedMLPs, or entity networks.

Where it sits: :class:`cmcl.learners.maddpg.MADDPG` calls `build_networks` once; every kind takes the same flat
inputs and gives the same shapes (actor [N, B, obs_dim] -> [N, B, act_dim]; critic on the joint input, shared rows
[M, in] -> [N, M, 1] or per-owner rows [N, S, in] -> [N, S, 1]), so nothing downstream depends on the kind.
"""

from __future__ import annotations

import torch
from torch import nn

from cmcl.config.learning import NETWORK_KINDS
from cmcl.envs.entities import EntityLayout
from cmcl.learners.entity.nets import EntityActor, EntityCritic
from cmcl.learners.nets import StackedMLP

__all__ = ["build_networks", "network_kind"]


def network_kind(networks: str) -> str:
    """`networks` when it is one of NETWORK_KINDS (the config checks the same at load and names its field)."""
    if networks not in NETWORK_KINDS:
        raise ValueError(f"networks must be one of {list(NETWORK_KINDS)}, got {networks!r}")
    return networks


def build_networks(kind: str, n: int, obs_dim: int, act_dim: int, widths: tuple[int, ...], discrete: bool,
                   gen: torch.Generator, layout: EntityLayout | None, pool: str = "attention", nearest: int = 0,
                   holder: bool = False, holder_rule: str = "nearest") -> tuple[nn.Module, nn.Module]:
    """(actor, critic) of the given kind: StackedMLPs with N members (per agent or shared), or entity networks
    (pooling over entities `pool`: entity_nets.POOLS; `nearest` > 0: only the k nearest entities of each kind,
    entity_nets.nearest_entities; `holder`: each entity row with its holder margin, entity_nets.holder_margin, by
    `holder_rule`)."""
    out_act = None if discrete else nn.Tanh
    if int(nearest) < 0:
        raise ValueError(f"nearest must be >= 0 (0: every entity), got {nearest!r}")
    if kind != "entity":
        if nearest:
            raise ValueError(f"nearest entities need entity networks, not {kind!r}")
        if holder:
            raise ValueError(f"the holder margin needs entity networks, not {kind!r}")
        share = kind == "shared"
        return (StackedMLP(n, obs_dim, widths, act_dim, out_act=out_act, generator=gen, share=share),
                StackedMLP(n, n * (obs_dim + act_dim), widths, 1, generator=gen, share=share))
    if layout is None or layout.num_agents != n or layout.obs_dim != obs_dim:
        raise ValueError(f"entity networks need the entity layout of {n} agents with obs_dim {obs_dim}, got "
                         f"{None if layout is None else (layout.num_agents, layout.obs_dim)}")
    if len(set(widths)) != 1:
        raise ValueError(f"entity networks take one hidden width, got {widths}")
    return (EntityActor(layout, act_dim, widths[0], gen, out_act=out_act, pool=pool, nearest=nearest, holder=holder,
                        holder_rule=holder_rule),
            EntityCritic(layout, act_dim, widths[0], gen, pool=pool, nearest=nearest, holder=holder,
                         holder_rule=holder_rule))

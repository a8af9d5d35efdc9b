"""Which entity rows an entity network reads: the opt-ins every entity network shares (cmcl.learners.entity.nets).

``nearest`` = k > 0 keeps the k nearest present entities of each kind (:func:`nearest_entities`,
maddpg.entity_nearest); ``holder`` appends every entity row's holder margin, computed over every entity before that
pick (cmcl.learners.entity.holder; navigation only, maddpg.entity_holder); ``holder_rule`` names which other agents
hold a landmark (maddpg.holder_rule, cmcl.learners.entity.holder_rules). Entity rows are float32[..., E, F] with a mask
bool[..., E]. The numpy twins the rollout workers run are in cmcl.rollout.policy (parity tested).
"""

from __future__ import annotations

import torch

from cmcl.envs.entities import EntityLayout
from cmcl.learners.entity.holder import holder_slots, holder_width, require_holder_rule, with_holder

__all__ = ["EntityOptIns", "nearest_entities", "type_columns"]


def type_columns(layout: EntityLayout) -> slice:
    """The columns of the type one-hot in an entity row (after the P raw features): nearest_entities, holder_margin."""
    raw = layout.entity_index.shape[2]
    return slice(raw, raw + len(layout.type_names))


def nearest_entities(entities: torch.Tensor, mask: torch.Tensor, k: int, types: slice
                     ) -> tuple[torch.Tensor, torch.Tensor]:
    """The k nearest present entities of each kind (an opt-in, ``nearest`` of the entity actor and critic; 0, the
    default, keeps them all): entities float32[..., E, F], whose first two features are the entity's position
    relative to the agent (every built-in layout, cmcl.envs.entities) and `types` the columns of the type one-hot,
    mask bool[..., E] -> float32[..., T·k', F], bool[..., T·k'] (k' = min(k, E); a kind with fewer than k' present
    entities fills its picks with absent ones). Closest first within a kind; ties go to the lower slot (as the
    numpy twin's, cmcl.rollout.policy.nearest_entities; which absent slots fill a kind's picks is not set)."""
    e = entities.shape[-2]
    kinds = entities[..., types].detach() > 0.5  # [..., E, T]
    dist = entities[..., :2].detach().square().sum(-1).masked_fill(~mask, float("inf"))  # [..., E]
    dist = dist.unsqueeze(-2).masked_fill(~kinds.transpose(-1, -2), float("inf"))  # [..., T, E]
    k = min(int(k), e)
    value, index = dist.topk(min(k + 1, e), -1, largest=False)  # [..., T, k' (+ 1)]: ties in no set order
    if bool(((value[..., 1:] == value[..., :-1]) & value[..., 1:].isfinite()).any()):  # rare: the lower slot first
        value, index = dist.sort(dim=-1, stable=True)
    value, index = value[..., :k], index[..., :k].flatten(-2)
    picked = entities.gather(-2, index.unsqueeze(-1).expand(*index.shape, entities.shape[-1]))
    return picked, value.flatten(-2).isfinite()


class EntityOptIns:
    """A mixin of the entity networks: ``nearest`` k, ``holder`` (the margin column, navigation only) and
    ``holder_rule`` (module docstring); :meth:`_opt_ins` applies them to entity rows float32[..., E, F] and their
    mask bool[..., E], the margin first (computed over every entity), then the pick of the k nearest."""

    def _set_opt_ins(self, layout: EntityLayout, nearest: int, holder: bool, holder_rule: str) -> None:
        self.nearest, self._type_cols = int(nearest), type_columns(layout)
        self.holder = bool(holder_width(layout, holder))
        self._holder_slots = holder_slots(layout) if self.holder else None
        self.holder_rule = require_holder_rule(holder_rule)

    def _opt_ins(self, ents: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        if self.holder:
            ents = with_holder(ents, mask, self._type_cols, self._holder_slots, self.holder_rule)
        if self.nearest:
            ents, mask = nearest_entities(ents, mask, self.nearest, self._type_cols)
        return ents, mask

"""The holder margin (maddpg.entity_holder, issue 38): one more entity feature of navigation's entity networks that
says, for every landmark, whether another agent holds it.

Why: at N = 8 the entity networks cover ~0.87 of the landmarks but rarely all of them; in nearly every unfinished
world two agents sit on one landmark while another stays free. A landmark's entity row shows where it is relative
to the viewing agent only, so whether some other agent is nearer to it is a relation between two entity rows, which
the pooling from the agent's own embedding cannot form. The margin puts that relation into the landmark's row.

For a present landmark l of agent i's view (r: positions relative to agent i, the first two entity features):

    m_l = min over the present other-agent entities j of ||r_j − r_l||  −  ||r_l||      (arena units)

negative when another agent is closer to l than agent i (it "holds" l), positive when agent i is the closest, and
HOLDER_ALONE (+2.0: more than any margin with an agent present, |m_l| <= the arena's diagonal √2 ≈ 1.41) when no
other agent is present; 0 for agent entities and for absent slots.
The entity actor, the entity critic (the learner's, its targets, the entity teachers) and the entity ICM append it
as the last column of every entity row (:func:`with_holder`), computed after the presence mask of rows carried from
fewer agents and before maddpg.entity_nearest's pick, so that a landmark's margin sees every present agent, not only
the k picked. Rollout workers' numpy twin is cmcl.learners.policy.holder_margin. No gradient flows through it (the
positions are observations).
"""

from __future__ import annotations

import torch

from cmcl.envs.entities import EntityLayout
from cmcl.learners.policy import HOLDER_ALONE

__all__ = ["HOLDER_ALONE", "holder_margin", "holder_width", "with_holder"]


def holder_margin(entities: torch.Tensor, mask: torch.Tensor, types: slice) -> torch.Tensor:
    """entities float32[..., E, F'] of navigation views (the first two features: the entity's position relative to
    the viewing agent; `types`: the columns of the type one-hot, landmark first, agent second), mask bool[..., E]
    (present entities) -> the holder margin float32[..., E, 1] (module docstring). Vectorised, detached."""
    pos = entities[..., :2].detach()
    kinds = entities[..., types].detach() > 0.5  # [..., E, T]
    landmark, agent = kinds[..., 0] & mask, kinds[..., 1] & mask  # [..., E]
    viewer = pos.square().sum(-1).sqrt()  # [..., E]: ||r_l||
    gap = (pos.unsqueeze(-2) - pos.unsqueeze(-3)).square().sum(-1).sqrt()  # [..., E (l), E (j)]: ||r_j − r_l||
    nearest = gap.masked_fill(~agent.unsqueeze(-2), float("inf")).amin(-1)  # [..., E]
    margin = torch.where(nearest.isfinite(), nearest - viewer, HOLDER_ALONE)
    return torch.where(landmark, margin, 0.0).unsqueeze(-1)


def with_holder(entities: torch.Tensor, mask: torch.Tensor, types: slice) -> torch.Tensor:
    """entities float32[..., E, F'] -> float32[..., E, F' + 1], the holder margin appended as the last column."""
    return torch.cat([entities, holder_margin(entities, mask, types)], -1)


def holder_width(layout: EntityLayout, holder: bool) -> int:
    """The entity columns the margin adds: 1 when `holder` (ValueError unless the layout is navigation's, whose
    entity types are landmark and agent), else 0."""
    if holder and layout.type_names != ("landmark", "agent"):
        raise ValueError(f"the holder margin (maddpg.entity_holder) needs navigation's entities (landmark, agent), "
                         f"got {list(layout.type_names)}")
    return int(bool(holder))

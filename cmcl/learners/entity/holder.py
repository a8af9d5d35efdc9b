"""The holder margin (maddpg.entity_holder): one more entity feature of navigation's entity networks that
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
the k picked. Rollout workers' numpy twin is cmcl.rollout.policy.holder_margin. No gradient flows through it (the
positions are observations).

The rule (maddpg.holder_rule) says which other agents count. "nearest" (the margin above): every present other
agent. "seated": an agent seated on a landmark (within SEATED_RADIUS, the default task's cover radius, of its nearest
present landmark; ties to the lowest slot) counts for that landmark only; an agent on no landmark counts for every
one. Where one agent sits within the cover radius of two landmarks (at N = 16, 56-64 % of the held-out worlds end
so, every landmark covered but not each by an agent of its own, cmcl.run.stalls), the landmark it is not nearest to
reads as held by the nearest agent that is not seated elsewhere (HOLDER_ALONE when every other agent is), not as held by
it. Until agents sit down the two rules give the same margins.
"""

from __future__ import annotations

import torch

from cmcl.envs.entities import EntityLayout
from cmcl.learners.entity.holder_rules import HOLDER_RULES, SEATED_RADIUS, require_holder_rule
from cmcl.rollout.policy import HOLDER_ALONE

__all__ = ["HOLDER_ALONE", "HOLDER_RULES", "SEATED_RADIUS", "holder_margin", "holder_slots", "holder_width",
           "require_holder_rule", "with_holder"]


def counted(to_landmarks: torch.Tensor, radius: float) -> torch.Tensor:
    """to_landmarks float32[..., L, A] (landmark l to agent j; inf where l is no present landmark or j is absent),
    radius: in the same units -> bool[..., L, A]: agent j counts as a possible holder of l under the "seated" rule
    (it sits on no landmark, or l is the one it sits on: its nearest, the lowest l on ties)."""
    nearest, first = to_landmarks.min(-2, keepdim=True)  # [..., 1, A]
    rows = torch.arange(to_landmarks.shape[-2], device=to_landmarks.device).view(-1, 1)
    return ~(nearest < radius) | (rows == first)


def holder_margin(entities: torch.Tensor, mask: torch.Tensor, types: slice, rule: str = "nearest") -> torch.Tensor:
    """entities float32[..., E, F'] of navigation views (the first two features: the entity's position relative to
    the viewing agent; `types`: the columns of the type one-hot, landmark first, agent second), mask bool[..., E]
    (present entities), rule: HOLDER_RULES -> the holder margin float32[..., E, 1] (module docstring). Vectorised,
    detached."""
    pos = entities[..., :2].detach()
    kinds = entities[..., types].detach() > 0.5  # [..., E, T]
    landmark, agent = kinds[..., 0] & mask, kinds[..., 1] & mask  # [..., E]
    viewer = pos.square().sum(-1).sqrt()  # [..., E]: ||r_l||
    gap = (pos.unsqueeze(-2) - pos.unsqueeze(-3)).square().sum(-1).sqrt()  # [..., E (l), E (j)]: ||r_j − r_l||
    held = agent.unsqueeze(-2)  # [..., 1, E]: which agents count for every landmark
    if rule == "seated":
        held = held & counted(gap.masked_fill(~landmark.unsqueeze(-1), float("inf")), SEATED_RADIUS)
    nearest = gap.masked_fill(~held, float("inf")).amin(-1)  # [..., E]
    margin = torch.where(nearest.isfinite(), nearest - viewer, HOLDER_ALONE)
    return torch.where(landmark, margin, 0.0).unsqueeze(-1)


def holder_margin_of_slots(entities: torch.Tensor, mask: torch.Tensor, landmarks: torch.Tensor,
                           agents: torch.Tensor, rule: str = "nearest") -> torch.Tensor:
    """:func:`holder_margin` where every row has its landmarks in slots `landmarks` int64[L] and its agents in slots
    `agents` int64[A] (`holder_slots`: a built-in layout's slot order): the same numbers, from the L x A landmark-agent
    distances only instead of the E x E table (about 4x less work; the actor's target pass reads N x N x S views
    per update). entities float32[..., E, F'], mask bool[..., E] -> float32[..., E, 1]."""
    pos = entities[..., :2].detach()
    lm, ag = pos[..., landmarks, :], pos[..., agents, :]  # [..., L, 2], [..., A, 2]
    dx = lm[..., :, None, 0] - ag[..., None, :, 0]  # [..., L, A]
    dy = lm[..., :, None, 1] - ag[..., None, :, 1]
    gap2 = (dx * dx + dy * dy).masked_fill(~mask[..., None, agents], float("inf"))
    if rule == "seated":  # an agent seated on one landmark holds no other
        present = mask[..., landmarks]  # [..., L]
        to_landmarks = gap2.masked_fill(~present.unsqueeze(-1), float("inf"))
        gap2 = gap2.masked_fill(~counted(to_landmarks, SEATED_RADIUS ** 2), float("inf"))
    nearest = gap2.amin(-1).sqrt()  # [..., L]: the nearest present (counted) agent's distance to each landmark
    viewer = (lm * lm).sum(-1).sqrt()  # [..., L]: ||r_l||
    margin = torch.where(nearest.isfinite(), nearest - viewer, HOLDER_ALONE)
    margin = torch.where(mask[..., landmarks], margin, 0.0)
    out = entities.new_zeros(*entities.shape[:-1])  # [..., E]: 0 for agents and absent slots
    return out.index_copy(out.dim() - 1, landmarks, margin).unsqueeze(-1)


def holder_slots(layout: EntityLayout) -> tuple[torch.Tensor, torch.Tensor] | None:
    """(landmark slots int64[L], agent slots int64[A]) when every agent's view has the same kind in each slot (every
    built-in navigation layout), for :func:`holder_margin_of_slots`; None otherwise (the generic margin)."""
    kinds = layout.entity_type.argmax(-1)  # [N, E]
    if not (kinds == kinds[:1]).all():
        return None
    return (torch.from_numpy((kinds[0] == 0).nonzero()[0].astype("int64")),
            torch.from_numpy((kinds[0] == 1).nonzero()[0].astype("int64")))


def with_holder(entities: torch.Tensor, mask: torch.Tensor, types: slice,
                slots: tuple[torch.Tensor, torch.Tensor] | None = None, rule: str = "nearest") -> torch.Tensor:
    """entities float32[..., E, F'] -> float32[..., E, F' + 1], the holder margin by `rule` (HOLDER_RULES) appended
    as the last column (from the layout's static `slots` when given, `holder_slots`; else the generic
    `holder_margin`)."""
    require_holder_rule(rule)
    margin = holder_margin(entities, mask, types, rule) if slots is None else \
        holder_margin_of_slots(entities, mask, *slots, rule=rule)
    return torch.cat([entities, margin], -1)


def holder_width(layout: EntityLayout, holder: bool) -> int:
    """The entity columns the margin adds: 1 when `holder` (ValueError unless the layout is navigation's, whose
    entity types are landmark and agent), else 0."""
    if holder and layout.type_names != ("landmark", "agent"):
        raise ValueError(f"the holder margin (maddpg.entity_holder) needs navigation's entities (landmark, agent), "
                         f"got {list(layout.type_names)}")
    return int(bool(holder))

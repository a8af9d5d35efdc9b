"""Which other agents hold a landmark, for the holder margin of the entity networks (maddpg.holder_rule): the rule
names, the seated radius, and the one-line refusal of another name. The rules themselves are computed in
cmcl.learners.entity.holder (torch) and cmcl.rollout.policy (the numpy twin); the config checks a run's rule here."""

from __future__ import annotations

# "nearest": a landmark is held by the agent nearest to it; "seated": an agent seated on a landmark (within
# SEATED_RADIUS of its nearest one) holds that one only
HOLDER_RULES = ("nearest", "seated")
# an agent this near its nearest landmark sits on it (world units): the default task's cover radius
# (cmcl.envs.params.SpreadParams.cover_radius), at which alone the config accepts the seated rule
SEATED_RADIUS = 0.1


def require_holder_rule(rule: str) -> str:
    """`rule` when it is one of HOLDER_RULES, else ValueError naming maddpg.holder_rule and the value."""
    if rule not in HOLDER_RULES:
        raise ValueError(f"maddpg.holder_rule must be one of {list(HOLDER_RULES)}, got {rule!r}")
    return rule

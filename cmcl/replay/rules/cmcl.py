"""cmcl: the paper's method (ALGORITHM.md): CI = KP(ĉ, λ) + η·CP(ρ̂), the K-fold teachers' difficulty and, with
η > 0, the ICM's curiosity, sampled by the curriculum sampler it shares with acl (cmcl.replay.rules.acl)."""

from __future__ import annotations

from cmcl.replay.rules.acl import KP_EXCLUDES, CurriculumSampling
from cmcl.replay.rules.contract import Needs, Rule

RULE = Rule("cmcl", "CI = KP(ĉ, λ) + η·CP(ρ̂): the paper's method", lambda args, options: CurriculumSampling(args),
            "cmcl", needs=lambda team: Needs(teachers=True, icm=team.eta > 0), uses_eta=True, paper=True,
            early_note=KP_EXCLUDES, uses_lambda=True)

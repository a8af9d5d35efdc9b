"""The screen's arms (protocol in lab/RESULTS.md, "Sampling rules that help: the screen"): the candidate
sampling rules and their references with their overrides, the screen's seeds, the permuted control's key and the rule
an arm's overrides name.

Where it sits: the grid registry (experiments.grids) runs these arms, the screen's selection rule
(experiments.screen_selection) and the report's table read them, and the confirmation (experiments.confirm_arms)
derives its arms from them; this module imports nothing of the experiments, so each of those reads it without
importing the registry.
"""

from __future__ import annotations

from collections.abc import Sequence

# The permuted control: a rule's own priorities shuffled across the buffer's rows at every recompute (same
# probabilities, hence the same ESS, no information about the rows; cmcl.replay.buffer), or for LaBER the fresh |δ| of
# each pick's candidates shuffled across them (cmcl.replay.rules.laber). The one place naming its key: the
# confirmation's controls (experiments.confirm_arms) and the curriculum grids' cmcl_permuted arm (experiments.grids)
# take it from here.
PERMUTED_CONTROL = "teams.<team>.priority.difficulty_transform=permuted"
# The screen of sampling rules (protocol in lab/RESULTS.md, "Sampling rules that help: the screen"): candidate sampling
# rules on the harder task in two rounds (below), every setting the harder grid's but the team's rule; MADDPG and
# PER-MADDPG beside them for reference (not candidates). arm -> --set overrides.
SCREEN_ARMS: dict[str, list[str]] = {
    "maddpg": ["teams.agent.algorithm=maddpg"],
    "per": ["teams.agent.algorithm=per"],
    "relo": ["teams.agent.algorithm=relo"],
    "rho": ["teams.agent.algorithm=rho"],
    "lp": ["teams.agent.algorithm=lp"],
    "per_floor": ["teams.agent.algorithm=per", "teams.agent.priority.uniform_floor=0.2"],
    "cmcl_lam05": ["teams.agent.algorithm=cmcl", "curriculum.lam0=0.5"],  # no exclusion phase (λ ≥ 0.5 from the start)
    "cmcl_floor": ["teams.agent.algorithm=cmcl", "teams.agent.priority.uniform_floor=0.2"],
    # added to the protocol on 2026-12-05 at 00:10 UTC, before any of its runs (lab/RESULTS.md)
    "laber": ["teams.agent.algorithm=laber"],
    # added on 2026-12-05 at 13:42 UTC, after 11 runs had been read and before any of its own (lab/RESULTS.md,
    # "Amendment: the screen in two rounds"): PER-MADDPG with its actor on uniform rows (Saglam et al. 2023)
    "per_actor_uniform": ["teams.agent.algorithm=per", "teams.agent.actor_batch=uniform"],
}
SCREEN_REFERENCES = ("maddpg", "per")  # run beside the candidates, never selected
# The screen in two rounds (amended on 2026-12-05 at 13:35 UTC, after 11 of the 45 runs of the first protocol had been
# read: lab/RESULTS.md, "Amendment: the screen in two rounds"). Round one: every arm at ROUND_ONE_SEEDS. Round two:
# ROUND_TWO_REFERENCES and the ROUND_ONE_KEPT best candidates of round one that acted, at ROUND_TWO_SEEDS
# (experiments.screen_selection.round_two_arms). The selection reads SCREEN_SEEDS; runs at other seeds (LaBER's 103 and
# 104, run before the amendment) are shown beside the table, never read.
ROUND_ONE_SEEDS = (100,)
ROUND_TWO_SEEDS = (101, 102)
ROUND_ONE_KEPT = 3
ROUND_TWO_REFERENCES = ("maddpg",)
SCREEN_SEEDS = ROUND_ONE_SEEDS + ROUND_TWO_SEEDS


def rule_algorithm(sets: Sequence[str]) -> str:
    """The sampling rule of a screen arm's overrides (the first of them: teams.agent.algorithm=<rule>)."""
    return sets[0].split("=")[1]

"""The teams' sections of a run configuration: [teams.<team>] (`TeamConfig`) and [teams.<team>.priority]
(`PriorityConfig`), one of each per team of the task.

Which algorithm (sampling rule, cmcl.replay.registry) a team of agents learns with and what its sampler turns scores
into sampling probabilities with (ALGORITHM.md §5). Every field is declared with `documented(default, meaning,
unit=..., rule=...)` (cmcl.field_docs), as in cmcl.config.learning; each `__post_init__` runs the rules
(`check_fields`) and raises `ConfigError` naming the key and the value. A team's derived settings (α_s, η, IS
weights, what its rule needs) come from the algorithm registry (cmcl.replay.registry.REGISTRY); which teams a task has
is cmcl.config.env's `TASK_TEAMS`. A team's rule's own options (its `Rule.options`, cmcl.replay.rules.contract) are
keys of the team's table, built into `TeamConfig.options` and range-checked here, once, with the team's path in the
message ("teams.agent.candidates must be >= 2, got 1"). Reads nothing but its own fields and the registry.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

from cmcl.config.checks import OPTIONAL_ALPHA, ConfigError, check_fields, rule
from cmcl.field_docs import documented
from cmcl.replay.registry import ALGORITHMS, REGISTRY

# α_s of eq. 20 when nothing sets it (ALGORITHM.md A8, revised 2026-12): each registered algorithm's default
# (cmcl.replay.registry: "proportional to the K-fold priority" for ACL and CMCL, Schaul's 0.6 for PER-MADDPG and ReLo)
DEFAULT_ALPHA = {name: spec.default_alpha for name, spec in REGISTRY.items()}
__all__ = ["DEFAULT_ALPHA", "PriorityConfig", "TeamConfig"]


class _Registered:
    """`teams.<team>.algorithm`'s range: a registered rule (read when checked, so a rule file registered at config
    load, replay.rule_files, is one)."""

    @property
    def why(self) -> str:
        return f"must be one of {list(REGISTRY)}"

    def ok(self, value: Any, section: Any) -> bool:
        return value in REGISTRY


@dataclass(frozen=True)
class PriorityConfig:
    """What one team's sampler turns scores into sampling probabilities with: one [teams.<team>.priority]
    table per team; each agent's sampler reads its own team's (cmcl.system.agent_layout)."""

    alpha: float | None = documented(
        None, "the team's sampling exponent α_s (eq. 20, A8); unset: its algorithm's default "
        "(cmcl.replay.registry: 0.6 for per and relo, 1 for the others)", rule=OPTIONAL_ALPHA)
    uniform_floor: float = documented(
        0.0, "u, the uniform floor of a prioritised rule: P = (1 − u)·P_rule + u/|D|; 0 = the rule alone; "
        "no effect on maddpg", rule=rule("must lie in [0, 1)", lambda v: math.isfinite(v) and 0 <= v < 1))
    difficulty_norm: Literal["max", "rank"] = documented(
        "rank", "ĉ of §3.3 (A1, revised 2026-12), for acl / cmcl: 'rank' = percentile over the buffer, "
        "rank/(|D|−1) (λ reads as a difficulty percentile, so KP excludes rows while λ < 0.5); 'max' = "
        "min(1, c / max c), the earlier default, which puts the heavy-tailed c at ĉ ≈ 0.05 (every row on KP's "
        "rising branch: near-uniform sampling, ESS >= 0.9)")
    difficulty_transform: Literal["none", "permuted", "reversed"] = documented(
        "none", "sampling controls, to tell 'the curriculum helps' from 'sampling is just different': "
        "'none' = the rule; 'reversed' = anti-curriculum, ĉ → 1 − ĉ before KP (eq. 12; acl / cmcl); 'permuted' = "
        "at each recompute the priority column of each of the team's agents is shuffled across the buffer's rows "
        "by a seeded permutation (cmcl.replay.priority.permute_priorities): the same multiset of probabilities, "
        "hence the same ESS, carrying no information about the rows (every rule whose priorities the buffer "
        "holds); for laber, each pick at the learner reads the fresh |δ| of its m·B candidates shuffled across "
        "them by a seeded permutation (cmcl.replay.rules.laber.candidate_orders): the same multiset of "
        "priorities and IS weights, no information about which candidate is hard; maddpg's uniform sampling is "
        "unaffected")
    difficulty_error: Literal["squared", "abs"] = documented(
        "squared", "the teachers' error on a row against the learner's TD target (eq. 10), for the team's agents: "
        "'squared' (δ²) or 'abs' (|δ|)")
    cp_input: Literal["std", "raw"] = documented(
        "std", "the curiosity the curiosity priority CP (eq. 19) reads (A7), for cmcl: 'std' = ρ divided by its "
        "standard deviation over the buffer, per agent; 'raw' = ρ as is")

    def __post_init__(self) -> None:
        check_fields(self, "priority")


@dataclass(frozen=True)
class TeamConfig:
    """Which algorithm a team of agents learns with (ALGORITHM.md §5): one [teams.<team>] table per team, its
    sampling settings in [teams.<team>.priority]."""

    algorithm: str = documented(
        "maddpg", "the team's algorithm, i.e. its replay's sampling rule (cmcl.replay.registry; unnamed: MADDPG's "
        "uniform replay, which no rule here has beaten, lab/RESULTS.md): " +
        "; ".join(f"'{name}' ({REGISTRY[name].summary})" for name in ALGORITHMS) +
        ". A rule's own options are keys of this table too (teams.<team>.<option>, listed below with their rule)",
        rule=_Registered())
    eta: float = documented(0.5, "η, the curiosity weight in CI = KP + η·CP (eq. 8, A15); forced to 0 for acl",
                            rule=rule("must be >= 0", lambda v: v >= 0 and math.isfinite(v)))
    is_correction: bool | None = documented(None, "importance-sampling weights on the critic loss; unset: the "
                                            "algorithm's default (on for per and relo, off for the others; A9)")
    acl_variant: Literal["teachers", "td_self"] = documented(
        "teachers", "where an acl team's difficulty comes from: 'teachers' (the K-fold teachers' errors, as cmcl) "
        "or 'td_self' (the learner's own |δ| on the row)")
    actor_batch: Literal["rule", "uniform"] = documented(
        "rule", "the rows the actor step trains on: 'rule' = the critic's minibatch, drawn by the team's rule; "
        "'uniform' = a minibatch of its own drawn uniformly from the buffer, apart from the critic's, without IS "
        "weights (actor prioritised replay, Saglam et al. 2023); accepted and without effect on maddpg, "
        "whose critic's minibatch is already uniform")
    priority: PriorityConfig = documented(
        factory=PriorityConfig, meaning="the team's sampling settings: the [teams.<team>.priority] table")
    options: Any = documented(
        None, "the rule's own options (its `Rule.options` dataclass, cmcl.replay.rules.contract), written as keys of "
        "the team's table; unset: the rule's defaults")

    def __post_init__(self) -> None:
        check_fields(self, "team")
        own = REGISTRY[self.algorithm].options
        if self.options is None:
            object.__setattr__(self, "options", own())
        elif type(self.options) is not own:
            raise ConfigError(f"team.options must be {own.__name__} (algorithm {self.algorithm!r}), got "
                              f"{type(self.options).__name__}")
        check_fields(self.options, "team")

    @property
    def rule(self):
        """This team's sampling rule (cmcl.replay.rules.contract.Rule)."""
        return REGISTRY[self.algorithm]

    def effective_alpha(self) -> float:
        """α_s this team samples with: its priority.alpha, else its algorithm's default (DEFAULT_ALPHA, from the
        registry)."""
        alpha = self.priority.alpha
        return self.rule.default_alpha if alpha is None else alpha

    @property
    def uniform_actor(self) -> bool:
        """Whether this team's actor trains on a uniform minibatch of its own (actor_batch = "uniform" under a rule
        that does not already draw the critic's uniformly)."""
        return self.actor_batch == "uniform" and self.rule.prioritised

    @property
    def needs(self):
        """What this team's sampling rule needs (cmcl.replay.registry.Needs: teachers, icm, learner scores)."""
        return self.rule.needs(self)

    @property
    def uses_teachers(self) -> bool:
        """True when this team's priority needs K-fold teacher difficulty scores."""
        return self.needs.teachers

    @property
    def uses_icm(self) -> bool:
        """True when this team's priority needs curiosity scores."""
        return self.needs.icm

    @property
    def effective_eta(self) -> float:
        """η as used in the priority: 0 for every algorithm whose rule has no η (all but CMCL)."""
        return self.eta if self.rule.uses_eta else 0.0

    @property
    def importance_weights(self) -> bool:
        """Whether IS weights correct this team's critic loss (its algorithm's default unless is_correction)."""
        return self.rule.importance_weights if self.is_correction is None else self.is_correction

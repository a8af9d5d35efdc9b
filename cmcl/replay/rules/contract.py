"""What a sampling rule declares about itself: `Rule`, the one object its file under cmcl/replay/rules/ exports as
`RULE`, and the types it is made of. The registry (cmcl.replay.registry) holds one line per rule; everything else
(the config, the system builder, the learner, the runners, the experiments) asks a `Rule` its capabilities and never
compares a rule's name.

A rule holds:
  options ............ its own config dataclass: the keys it adds to its team's table, `teams.<team>.<option>`
                       (fields declared with cmcl.field_docs.documented: meaning, unit, range rule, checked once
                       at config load, each failure one line naming `teams.<team>.<option>` and the value)
  sampler ............ how one agent's sampler is built: (SamplerArgs, options) -> the sampler protocol of
                       cmcl.replay.sampling (the buffer receives the built samplers and never asks their kind)
  needs .............. what the other roles must score for it (teachers, the ICM, learner scores), given the team
  learner_scores ..... the per-row scores the learner computes for it after each update (`LearnerScore`: a name and
                       a function of the update's stats and minibatch -> float[N, S]), fed back to its sampler
  candidates, pick ... a learner-side pick: the learner draws candidates(options)·B rows per owner and `pick`
                       chooses B of them (LaBER)
  capabilities ....... default α_s and IS weights, uses_eta, uses_lambda, masks_absent_agents, paper, early_note
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cmcl.replay.sampling import SamplerArgs


@dataclass(frozen=True)
class Range:
    """The allowed range of a rule's option (its field's `rule`, cmcl.field_docs.documented): `why` is the
    error's and the reference's text ("must be >= 2"); the config checks `ok` once at load (cmcl.config.teams)."""

    why: str
    test: Callable[[Any], bool]

    def ok(self, value: Any, section: Any) -> bool:
        """Whether `value` lies in the range (`section`: the options, unused)."""
        return bool(self.test(value))


@dataclass(frozen=True)
class NoOptions:
    """A rule without options of its own: its team's table adds no key."""


@dataclass(frozen=True)
class Needs:
    """What one team's agents need from the other roles: teachers (the K-fold difficulty column), icm (the
    curiosity column), learner_scores (the names of the learner's per-row scores fed back to the sampler: "td_abs"
    and those of the rule's own `LearnerScore`s), difficulty_source ("difficulty" from the teachers, or "td_abs":
    ACL td_self's own |δ|)."""

    teachers: bool = False
    icm: bool = False
    learner_scores: tuple[str, ...] = ()
    difficulty_source: str = "difficulty"


@dataclass(frozen=True)
class LearnerScore:
    """One per-row score the learner computes for a rule after each update: `of(stats, minibatch)` -> float[N, S]
    >= 0 (stats: what MADDPG.update returned, e.g. "td_abs" |y − Q| [N, S], "target_td_abs" |y − Q_target| [N, S];
    minibatch: the update's rows [N, S, ...]). It travels as cmcl.replay.messages.LearnerFeedback.rule_scores under
    `name` and reaches the agent's sampler's `feedback` as scores[name] float[k]. `target_critic`: it needs MADDPG's
    pre-step target-critic errors ("target_td_abs" in stats)."""

    name: str
    of: Callable[[dict[str, Any], dict[str, np.ndarray]], np.ndarray]
    target_critic: bool = False


def _no_needs(team: Any) -> Needs:
    return Needs()


def _one(options: Any) -> int:
    return 1


@dataclass(frozen=True)
class Rule:
    """One registered sampling rule (the module docstring).

    name: the config's `teams.<team>.algorithm`. summary: one line for --help, docs and reports. sampler: (args,
    options) -> the sampler of one agent. sampling: its distribution's name in the metrics ("sampling.modes").
    default_alpha: α_s when no config sets one (A8). importance_weights: IS weights on the critic when
    `is_correction` is unset (A9). needs: team -> Needs (the team has eta, acl_variant, options). options: its
    options' dataclass (NoOptions: none). learner_scores: the learner's scores of its own (LearnerScore). uses_eta: η
    enters its priority. uses_lambda: λ enters its priority (the progress line shows λ only then).
    masks_absent_agents: every score it samples by is computed with the mask of absent agents, so it may sample rows
    carried from fewer agents (run.carry_replay). draws_uniformly: its sampler draws every row alike. paper: one of
    the paper's four compared algorithms (ALGORITHM.md §5). early_note: what is normal while λ < 0.5 ("" = nothing
    to say). candidates: options -> m, the learner picks each minibatch among m·B rows (1: it takes them). pick:
    the learner-side pick, (priority float[N, M], u float[N, B], order int64[N, M] | None) -> (idx int64[N, B],
    weights float32[N, B]); None without candidates."""

    name: str
    summary: str
    sampler: Callable[[SamplerArgs, Any], Any]
    sampling: str
    default_alpha: float = 1.0
    importance_weights: bool = False
    needs: Callable[[Any], Needs] = _no_needs
    options: type = NoOptions
    learner_scores: tuple[LearnerScore, ...] = field(default=())
    uses_eta: bool = False
    uses_lambda: bool = False
    masks_absent_agents: bool = False
    draws_uniformly: bool = False
    paper: bool = False
    early_note: str = ""
    candidates: Callable[[Any], int] = _one
    pick: Callable[..., tuple[np.ndarray, np.ndarray]] | None = None

    @property
    def prioritised(self) -> bool:
        """Whether the rows the critic trains on are drawn other than uniformly (every rule but uniform replay: a
        learner-side pick among uniform candidates is prioritised too). A team's `actor_batch` = "uniform" acts on
        these rules only."""
        return self.pick is not None or not self.draws_uniformly

"""The learning sections of a run configuration: [maddpg], [replay], [curriculum], [teachers] and [icm].

What the base learner, the replay buffer, the curriculum factor λ, the K-fold teacher critics and the curiosity
module are built with, one frozen, self-validating dataclass per section. Every field has the paper's Table 1 value
or the resolution of ALGORITHM.md §5 as its default and is declared with `documented(default, meaning,
unit=..., rule=...)` (cmcl.field_docs): its meaning, unit and range check live there, once, and
`python -m cmcl config` / docs/CONFIG.md print them. Each `__post_init__` runs the rules (`check_fields`) and raises
`ConfigError` naming the full key (e.g. ``maddpg.gamma``) and the value. The teams' sections are
cmcl.config.teams, [run] and [service] cmcl.config.run_and_service, [env] cmcl.config.env; the value checks
(`ConfigError`, `_require`, ...) are cmcl.config.checks. Reads nothing but its own fields.
"""

from __future__ import annotations

import math
import typing
from dataclasses import dataclass
from typing import Literal

from cmcl.config.checks import (
    AT_LEAST_0,
    AT_LEAST_1,
    FINITE_AT_LEAST_0,
    OPEN_PROBABILITY,
    POSITIVE,
    PROBABILITY,
    Rule,
    _require,
    check_fields,
    rule,
)
from cmcl.field_docs import documented

NetworkKind = Literal["per_agent", "shared", "entity"]
NETWORK_KINDS: tuple[str, ...] = typing.get_args(NetworkKind)
__all__ = ["NETWORK_KINDS", "CurriculumConfig", "ICMConfig", "MADDPGConfig", "ReplayConfig", "TeacherConfig"]


@dataclass(frozen=True)
class MADDPGConfig:
    """Base learner (ALGORITHM.md §2, Table 1)."""

    actor_lr: float = documented(1e-3, "Adam learning rate of the actor networks (eq. 4)", rule=POSITIVE)
    critic_lr: float = documented(1e-3, "Adam learning rate of the critic networks (eq. 5)", rule=POSITIVE)
    gamma: float = documented(0.99, "discount factor γ of the critics' TD target (eq. 5)", rule=PROBABILITY)
    tau: float = documented(0.01, "soft target-network update rate τ (eq. 6): target ← τ·online + (1 − τ)·target "
                            "after every update", rule=OPEN_PROBABILITY)
    hidden: int = documented(64, "width of each hidden layer of the actor and critic networks", unit="units",
                             rule=AT_LEAST_1)
    batch_size: int = documented(128, "transitions per minibatch of one learner update; must not exceed "
                                 "maddpg.warmup (unless that is 0)", unit="transitions", rule=AT_LEAST_1)
    grad_clip: float = documented(0.5, "gradient-norm clip of every actor and critic step, per agent",
                                  rule=POSITIVE)
    exploration_std: float = documented(0.1, "standard deviation of the Gaussian noise on the tanh actions "
                                        "(exploration)", unit="action units", rule=AT_LEAST_0)
    discrete: bool = documented(False, "Gumbel-softmax actors over the built-in tasks' 5-way discrete action (A17); "
                                "must be false with env.factory")
    warmup: int = documented(3840, "transitions stored before the first learner update: batch × episode length "
                             "(A18); must not exceed replay.capacity", unit="transitions", rule=AT_LEAST_0)
    update_every: int = documented(
        16, "world steps (one step of one world = one transition) per learner update; 16 solves navigation fastest "
        "in wall clock (docs/LEARNING.md, python -m experiments run schedule); the paper presets (configs/paper/) "
        "use 1 (A18)", unit="world steps per update", rule=AT_LEAST_1)
    networks: NetworkKind = documented(
        "per_agent", "the networks' kind: 'per_agent' (one actor and critic per agent, the paper's), 'shared' "
        "(one actor and one critic network for all agents, each with its own first-layer bias, an agent-id "
        "embedding, cmcl.learners.nets; for N = 8 / 16, bench/scale.py) or 'entity' (one attention actor and one "
        "permutation-invariant critic for all agents over the observation's entities, a parameter count independent "
        "of N: cmcl.learners.entity.nets; built-in tasks only)")
    entity_pool: Literal["attention", "mean", "relational"] = documented(
        "attention", "how every entity network of the run (learner, teachers.networks and icm.networks = "
        "'entity') pools its entities: 'attention' (one head from the agent's own embedding, plus a mean), 'mean' "
        "(the mean only, about half the cost per update) or 'relational' ('attention' after one round of "
        "self-attention among the entities, so that a landmark's embedding can say another agent holds it: "
        "cmcl.learners.entity.nets)")
    entity_nearest: int = documented(
        0, "k > 0: the learner's entity actor and critic read only the k nearest present entities of each kind "
        "(navigation: landmarks, other agents; predator-prey: obstacles, predators, prey), closest first, so each "
        "agent's view has T·k entity rows instead of E (T kinds, E slots; E = 63 at N = 32), which is what the "
        "entity networks' cost grows with (cmcl.learners.entity.nets.nearest_entities). Rollout workers' numpy "
        "actor picks the same entities (cmcl.rollout.policy); entity teachers (teachers.networks = 'entity') and "
        "an entity ICM (icm.networks = 'entity') read the same k. Needs maddpg.networks = 'entity'. 0 = every "
        "entity", unit="entities per kind",
        rule=AT_LEAST_0)
    entity_holder: bool = documented(
        False, "navigation only (the crowding of two agents on one landmark): every entity row of the "
        "entity networks gets one more feature, the landmark's holder margin, the distance from it to the nearest "
        "other present agent minus the viewer's own distance to it (< 0: another agent holds it; 0 for agents; +2, "
        "more than any agent leaves, with no other agent; cmcl.learners.entity.holder), computed before "
        "maddpg.entity_nearest's pick. The learner's actor and critic, rollout workers' numpy actor, entity teachers "
        "and an entity ICM read it; it costs one more input of the entity layer and the N × (N − 1) landmark-to-agent "
        "distances of each view (1.18x the entity update at N = 8, docs/PERFORMANCE.md). Needs maddpg.networks = "
        "'entity' and env.task = 'spread'; a checkpoint or a run.init_from of the other value is refused (the entity "
        "layers' shapes differ). False = off; on in the presets configs/spread_n8.toml, spread_n16.toml and "
        "spread_n32.toml")
    holder_rule: Literal["nearest", "seated"] = documented(
        "nearest", "which other agents count as holding a landmark in maddpg.entity_holder's margin ("
        "cmcl.learners.entity.holder): 'nearest', every other present agent; 'seated', an agent within 0.1 (the "
        "default cover radius) of its nearest landmark counts for that landmark only, so a landmark it covers beside "
        "its own reads as held by the nearest agent not seated elsewhere (at N = 16 most unfinished worlds have "
        "every landmark covered but not each by an agent of its own, one agent on two). Needs maddpg.entity_holder = "
        "true and env.cover_radius = 0.1; recorded in checkpoints (a resume or an evaluation under the other "
        "rule is refused; a warm start, run.init_from, may change it: the weights fit either way)")
    assignment_loss: float = documented(
        0.0, "weight β of an auxiliary cross-entropy on the entity actor's attention over landmarks toward the "
        "landmark a minimum-total-distance assignment of agents to landmarks gives this agent, added to the actor "
        "loss (cmcl.learners.entity.assignment); needs maddpg.networks = 'entity', maddpg.entity_pool "
        "'attention' or 'relational' (with 'attention' a landmark's logit sees the agent and that landmark only, "
        "not the other agents), maddpg.entity_nearest = 0 and env.task = 'spread'. 0 = off", rule=FINITE_AT_LEAST_0)

    def __post_init__(self) -> None:
        check_fields(self, "maddpg")
        _require(self.entity_nearest == 0 or self.networks == "entity", "maddpg.entity_nearest",
                 self.entity_nearest, f"> 0 needs maddpg.networks = 'entity' (maddpg.networks = "
                 f"{self.networks!r} here)")
        _require(not self.entity_holder or self.networks == "entity", "maddpg.entity_holder", self.entity_holder,
                 f"needs maddpg.networks = 'entity' (maddpg.networks = {self.networks!r} here)")
        _require(self.holder_rule == "nearest" or self.entity_holder, "maddpg.holder_rule", self.holder_rule,
                 "needs maddpg.entity_holder = true (the rule is the holder margin's)")



@dataclass(frozen=True)
class ReplayConfig:
    """Replay storage and prioritized sampling (ALGORITHM.md §3.1, §3.6)."""

    capacity: int = documented(5000, "rows the replay buffer holds (eq. 3's B), one per world step; the oldest is "
                               "overwritten first. 5000 holds 166 episodes of the built-in tasks' 30 steps but only 16 "
                               "of Push-Box's 300: on sparse tasks the learner forgets the few rewards it found (the "
                               "sparse presets use 500,000; docs/SPARSE_TASKS.md)", unit="transitions", rule=AT_LEAST_1)
    priority_eps: float = documented(1e-6, "ε_p, the floor added to every priority (no row has probability 0)",
                                     rule=POSITIVE)
    beta_is_start: float = documented(0.4, "PER importance-sampling exponent β at the start of training, annealed "
                                      "linearly to replay.beta_is_end", rule=PROBABILITY)
    beta_is_end: float = documented(1.0, "PER importance-sampling exponent β at the end of training",
                                    rule=PROBABILITY)
    backend: Literal["cdf", "sumtree"] = documented(
        "cdf", "the samplers' structure (cmcl.replay.sampler): 'cdf' (inverse CDF) or 'sumtree' (a vectorised sum "
        "tree); both draw from the same distribution")
    rule_files: str = documented(
        "", "sampling rules kept in Python files of their own outside cmcl/replay/rules/ (each defining RULE, a "
        "cmcl.replay.rules.contract.Rule), paths separated by ':'; each is registered at config load, in every "
        "process of the run, before the teams' tables are read; '' = none")

    def __post_init__(self) -> None:
        check_fields(self, "replay")

    @property
    def rule_paths(self) -> list[str]:
        """The paths of `rule_files`, in order."""
        return [p for p in self.rule_files.split(":") if p]


@dataclass(frozen=True)
class CurriculumConfig:
    """Curriculum factor λ schedule (ALGORITHM.md §3.7)."""

    lam0: float = documented(0.1, "λ at the end of the warm-up: the difficulty the K-fold priority KP favours "
                             "first (eq. 12)", rule=Rule("must lie in (0, lam_max]", lambda value, section: (
                                 not OPEN_PROBABILITY.ok(section.lam_max, section) or 0 < value <= section.lam_max)))
    # (lam0's rule passes while lam_max is itself out of range: lam_max's own error is the one raised)
    lam_max: float = documented(1.0, "the largest λ, where the schedule stops", rule=OPEN_PROBABILITY)
    stride: float = documented(0.0, "Δλ per post-warm-up env step (kind = 'linear'); 0 means 'reach lam_max at "
                               "half of run.episodes' (3e-6 for 20k episodes)", unit="λ per env step",
                               rule=AT_LEAST_0)
    kind: Literal["linear", "multiplicative"] = documented(
        "linear", "how λ grows: 'linear' (λ_0 + Δλ·t) or 'multiplicative' (λ_0·(1 + κ)^t, κ reaching lam_max at "
        "half of training; CHER-style), t in post-warm-up env steps, capped at lam_max (cmcl.replay.curriculum)")

    def __post_init__(self) -> None:
        check_fields(self, "curriculum")


@dataclass(frozen=True)
class TeacherConfig:
    """K-fold teacher critics (ALGORITHM.md §3.2, A13, A14)."""

    num_folds: int = documented(5, "K: the buffer's rows are split by episode into K folds, and each agent has K "
                                "teacher critics, each fitted on its own fold (§3.2)", unit="folds",
                                rule=rule("must be >= 2", lambda v: v >= 2))
    batch_size: int = documented(128, "transitions per teacher fit batch", unit="transitions", rule=AT_LEAST_1)
    lr: float = documented(1e-3, "Adam learning rate of the teacher critics (eq. 9)", rule=POSITIVE)
    hidden: int = documented(64, "width of each hidden layer of a teacher critic", unit="units", rule=AT_LEAST_1)
    fit_batch: Literal["shared", "per_agent"] = documented(
        "shared", "'shared': one fold batch per fold serves every agent's teacher of that fold (one target pass; "
        "the service's layout); 'per_agent': each (agent, fold) teacher draws its own batch (§3.2 literally, A × "
        "the target cost)")
    steps_per_update: float = documented(
        0.5, "teacher fit steps per learner update, inline and in the service (its rate limiter); §3.8 has 1, the "
        "default 0.5 halves the teachers' cost (CMCL update cost vs MADDPG: bench/learner_throughput.py)",
        unit="fit steps per update", rule=POSITIVE)
    networks: NetworkKind = documented(
        "per_agent", "the teachers' kind: 'per_agent' (one network per (agent, fold)), 'shared' (one teacher "
        "network per fold for all agents, each agent with its own first-layer bias, cmcl.learners.nets, grouped "
        "sharing; the folds stay separate; for N = 8 / 16, bench/scale.py) or 'entity' (one entity critic, "
        "cmcl.learners.entity.nets, per fold for all agents, its parameter count independent of N)")

    def __post_init__(self) -> None:
        check_fields(self, "teachers")


@dataclass(frozen=True)
class ICMConfig:
    """Intrinsic curiosity module (ALGORITHM.md §3.4–3.5, A5–A7)."""

    feature_dim: int = documented(32, "size of the encoder's feature vector φ(s) (eq. 13)", unit="features",
                                  rule=AT_LEAST_1)
    hidden: int = documented(64, "width of each hidden layer of the encoder, inverse and forward models",
                             unit="units", rule=AT_LEAST_1)
    beta_forward: float = documented(0.2, "β of the ICM objective (eq. 17): the forward loss's weight against the "
                                     "inverse loss's 1 − β", rule=PROBABILITY)
    lr: float = documented(1e-3, "Adam learning rate of the ICM (eq. 17)", rule=POSITIVE)
    batch_size: int = documented(128, "transitions per ICM fit batch", unit="transitions", rule=AT_LEAST_1)
    intrinsic_reward_coef: float = documented(
        0.0, "weight of the curiosity ρ added to each curiosity agent's reward in the learner's minibatches: the "
        "row's ρ as the ICM scorer last scored it (0 until it has; both runners); 0 (A6): curiosity feeds the "
        "priority only. > 0 makes every agent a curiosity agent (the ICM role trains for all of them), whatever its "
        "team's sampling rule: MADDPG's uniform sampling with curiosity as a reward is algorithm 'maddpg' with this "
        "> 0 (docs/SPARSE_TASKS.md)", rule=AT_LEAST_0)
    intrinsic_reward_decay: Literal["none", "linear", "exponential"] = documented(
        "none", "how the weight falls over the learner's updates t: 'none' = coef throughout; 'linear' = coef · max(0, "
        "1 − t / intrinsic_reward_decay_updates); 'exponential' = coef · exp(−t / intrinsic_reward_decay_updates)")
    intrinsic_reward_decay_updates: int = documented(
        100_000, "the decay's length: learner updates (all agents at once, maddpg.updates) until the linear weight "
        "reaches 0, or over which the exponential one falls by e", unit="learner updates", rule=AT_LEAST_1)
    frozen: bool = documented(
        False, "never fit the ICM: ρ is the forward error of its randomly initialised networks (the intrinsic "
        "reward's control arm: a reward of the same kind from a random network, without curiosity's information; "
        "docs/SPARSE_TASKS.md). The fit steps are still paced and counted, their batches unused")
    steps_per_update: float = documented(0.5, "ICM fit steps per learner update, inline and in the service "
                                         "(§3.8: 1)", unit="fit steps per update", rule=POSITIVE)
    networks: Literal["per_agent", "entity"] = documented(
        "per_agent", "'per_agent': one encoder, inverse and forward model per curiosity agent; 'entity': one of "
        "each for all of them, the encoder over the observation's entities (cmcl.learners.entity.nets), a size "
        "independent of N")

    def __post_init__(self) -> None:
        check_fields(self, "icm")

    def intrinsic_coef(self, updates: int) -> float:
        """The weight of ρ in the reward at learner update `updates` (intrinsic_reward_decay's schedule)."""
        c, t, length = self.intrinsic_reward_coef, float(updates), float(self.intrinsic_reward_decay_updates)
        if self.intrinsic_reward_decay == "linear":
            return c * max(0.0, 1.0 - t / length)
        if self.intrinsic_reward_decay == "exponential":
            return c * math.exp(-t / length)
        return c

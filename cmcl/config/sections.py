"""The section dataclasses of a run configuration: one frozen, self-validating dataclass per component.

Every field has the paper's Table 1 value or the resolution of ../shared/ALGORITHM.md §5 as its default. Each field
is declared with `documented(default, meaning, unit=..., rule=...)` (cmcl.field_docs): its meaning, unit and range
check live there, once, and `python -m cmcl config` / docs/CONFIG.md print them. Each `__post_init__` runs the rules
(`check_fields`) and raises `ConfigError` naming the full key (e.g. ``maddpg.gamma``) and the value.
The whole run (`Config`) is in cmcl.config.experiment, the [env] section (`EnvConfig`) in cmcl.config.env; TOML
loading in cmcl.config.toml_io; the value checks (`ConfigError`, `_require`, ...) in cmcl.config.checks.
"""

from __future__ import annotations

import math
import typing
from dataclasses import dataclass
from typing import Literal

from cmcl.algorithms import ALGORITHMS, REGISTRY, AlgorithmName
from cmcl.config.checks import (
    AT_LEAST_0,
    AT_LEAST_1,
    FINITE_AT_LEAST_0,
    OPEN_PROBABILITY,
    OPTIONAL_ALPHA,
    POSITIVE,
    PROBABILITY,
    ConfigError,
    Rule,
    _require,
    check_fields,
    rule,
)
from cmcl.field_docs import documented

TaskName = Literal["spread", "tag"]
NetworkKind = Literal["per_agent", "shared", "entity"]
NETWORK_KINDS: tuple[str, ...] = typing.get_args(NetworkKind)
TASKS: tuple[str, ...] = typing.get_args(TaskName)
TASK_TEAMS = {"spread": ("agent",), "tag": ("predator", "prey")}  # teams of each task, in agent order
# α_s of eq. 20 when nothing sets it (ALGORITHM.md A8, revised 2026-12): each registered algorithm's default
# (cmcl.algorithms: "proportional to the K-fold priority" for ACL and CMCL, Schaul's 0.6 for PER-MADDPG and ReLo)
DEFAULT_ALPHA = {name: spec.default_alpha for name, spec in REGISTRY.items()}
__all__ = ["ALGORITHMS", "DEFAULT_ALPHA", "TASKS", "TASK_TEAMS", "ConfigError",
           "CurriculumConfig", "ICMConfig", "MADDPGConfig", "PriorityConfig", "ReplayConfig", "RunConfig",
           "ServiceConfig", "TeacherConfig", "TeamConfig"]


def _check_networks(section: str, networks: str | None, share_parameters: bool) -> None:
    """A section's `networks` is a known kind and agrees with its `share_parameters` (which means 'shared')."""
    if share_parameters and networks not in (None, "shared"):
        raise ConfigError(f"{section}.share_parameters = true contradicts {section}.networks = {networks!r}: set "
                          f"only {section}.networks (share_parameters = true means networks = 'shared')")
    _require(networks in (None, *NETWORK_KINDS), f"{section}.networks", networks,
             f"must be one of {list(NETWORK_KINDS)}")


def _network_kind(networks: str | None, share_parameters: bool) -> str:
    return networks if networks is not None else ("shared" if share_parameters else "per_agent")


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
    share_parameters: bool = documented(
        False, "one actor and one critic network for all agents, each with its own first-layer bias (an agent-id "
        "embedding, cmcl.learners.nets); for N = 8 / 16 (bench/scale.py). False = the paper's per-agent networks")
    networks: NetworkKind | None = documented(
        None, "the networks' kind (issue 22): 'per_agent' (one actor and critic per agent, the paper's), 'shared' "
        "(the same as share_parameters = true) or 'entity' (one attention actor and one permutation-invariant "
        "critic for all agents over the observation's entities, a parameter count independent of N: "
        "cmcl.learners.entity_nets; built-in tasks only). Unset: 'shared' if share_parameters else 'per_agent'")
    entity_pool: Literal["attention", "mean", "relational"] = documented(
        "attention", "how every entity network of the run (learner, teachers.networks and icm.networks = "
        "'entity') pools its entities: 'attention' (one head from the agent's own embedding, plus a mean), 'mean' "
        "(the mean only, about half the cost per update) or 'relational' ('attention' after one round of "
        "self-attention among the entities, so that a landmark's embedding can say another agent holds it: "
        "cmcl.learners.entity_nets)")

    def __post_init__(self) -> None:
        _check_networks("maddpg", self.networks, self.share_parameters)
        check_fields(self, "maddpg")

    @property
    def network_kind(self) -> str:
        """The networks built: maddpg.networks, or what share_parameters implies when it is unset."""
        return _network_kind(self.networks, self.share_parameters)


@dataclass(frozen=True)
class ReplayConfig:
    """Replay storage and prioritized sampling (ALGORITHM.md §3.1, §3.6)."""

    capacity: int = documented(5000, "rows the replay buffer holds (eq. 3's B), one per world step; the oldest is "
                               "overwritten first", unit="transitions", rule=AT_LEAST_1)
    priority_eps: float = documented(1e-6, "ε_p, the floor added to every priority (no row has probability 0)",
                                     rule=POSITIVE)
    beta_is_start: float = documented(0.4, "PER importance-sampling exponent β at the start of training, annealed "
                                      "linearly to replay.beta_is_end", rule=PROBABILITY)
    beta_is_end: float = documented(1.0, "PER importance-sampling exponent β at the end of training",
                                    rule=PROBABILITY)
    backend: Literal["cdf", "sumtree"] = documented(
        "cdf", "the samplers' structure (cmcl.replay.sampler): 'cdf' (inverse CDF) or 'sumtree' (a vectorised sum "
        "tree); both draw from the same distribution")

    def __post_init__(self) -> None:
        check_fields(self, "replay")


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
    rescore_rows_per_update: int = documented(
        128, "rows rescored per learner update (every never-scored row, then the oldest scores, "
        "cmcl.replay.scoring): the whole 5000-row buffer every ~39 updates; the paper preset's 167 = all of it "
        "every 30 updates (§3.8)", unit="rows per update", rule=AT_LEAST_1)
    fit_batch: Literal["shared", "per_agent"] = documented(
        "shared", "'shared': one fold batch per fold serves every agent's teacher of that fold (one target pass; "
        "the service's layout); 'per_agent': each (agent, fold) teacher draws its own batch (§3.2 literally, A × "
        "the target cost)")
    steps_per_update: float = documented(
        0.5, "teacher fit steps per learner update, inline and in the service (its rate limiter); §3.8 has 1, the "
        "default 0.5 halves the teachers' cost (CMCL update cost vs MADDPG: bench/learner_throughput.py)",
        unit="fit steps per update", rule=POSITIVE)
    share_parameters: bool = documented(
        False, "one teacher network per fold for all agents, each agent with its own first-layer bias "
        "(cmcl.learners.nets, grouped sharing); the folds stay separate. For N = 8 / 16 (bench/scale.py). False = "
        "per-(agent, fold) networks")
    networks: NetworkKind | None = documented(
        None, "the teachers' kind, as maddpg.networks: 'entity' = one entity critic (cmcl.learners.entity_nets) per "
        "fold for all agents, its parameter count independent of N; unset: 'shared' if share_parameters else "
        "'per_agent'")

    def __post_init__(self) -> None:
        _check_networks("teachers", self.networks, self.share_parameters)
        check_fields(self, "teachers")

    @property
    def network_kind(self) -> str:
        """The teachers' networks: teachers.networks, or what share_parameters implies when it is unset."""
        return _network_kind(self.networks, self.share_parameters)


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
    intrinsic_reward_coef: float = documented(0.0, "weight of the curiosity ρ added to the reward; 0 (A6): "
                                              "curiosity feeds priority only", rule=AT_LEAST_0)
    steps_per_update: float = documented(0.5, "ICM fit steps per learner update, inline and in the service "
                                         "(§3.8: 1)", unit="fit steps per update", rule=POSITIVE)
    networks: Literal["per_agent", "entity"] = documented(
        "per_agent", "'per_agent': one encoder, inverse and forward model per curiosity agent; 'entity': one of "
        "each for all of them, the encoder over the observation's entities (cmcl.learners.entity_nets), a size "
        "independent of N")

    def __post_init__(self) -> None:
        check_fields(self, "icm")


@dataclass(frozen=True)
class PriorityConfig:
    """What one team's sampler turns scores into sampling probabilities with (issue 36): one [teams.<team>.priority]
    table per team; each agent's sampler reads its own team's (cmcl.system.agent_layout)."""

    alpha: float | None = documented(
        None, "the team's sampling exponent α_s (eq. 20, A8); unset: its algorithm's default (cmcl.algorithms: 0.6 "
        "for per and relo, 1 for the others)", rule=OPTIONAL_ALPHA)
    uniform_floor: float = documented(
        0.0, "u, the uniform floor of a prioritised rule: P = (1 − u)·P_rule + u/|D| (issue 36); 0 = the rule alone; "
        "no effect on maddpg", rule=rule("must lie in [0, 1)", lambda v: math.isfinite(v) and 0 <= v < 1))
    difficulty_norm: Literal["max", "rank"] = documented(
        "rank", "ĉ of §3.3 (A1, revised 2026-12), for acl / cmcl: 'rank' = percentile over the buffer, "
        "rank/(|D|−1) (λ reads as a difficulty percentile, so KP excludes rows while λ < 0.5); 'max' = "
        "min(1, c / max c), the earlier default, which puts the heavy-tailed c at ĉ ≈ 0.05 (every row on KP's "
        "rising branch: near-uniform sampling, ESS >= 0.9)")
    difficulty_transform: Literal["none", "permuted", "reversed"] = documented(
        "none", "sampling controls (issue 21), to tell 'the curriculum helps' from 'sampling is just different': "
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

    algorithm: AlgorithmName = documented(
        "cmcl", "the team's algorithm, i.e. its replay's sampling rule (cmcl.algorithms): " +
        "; ".join(f"'{name}' ({spec.summary})" for name, spec in REGISTRY.items()))
    eta: float = documented(0.5, "η, the curiosity weight in CI = KP + η·CP (eq. 8, A15); forced to 0 for acl",
                            rule=rule("must be >= 0", lambda v: v >= 0 and math.isfinite(v)))
    is_correction: bool | None = documented(None, "importance-sampling weights on the critic loss; unset: the "
                                            "algorithm's default (on for per and relo, off for the others; A9)")
    acl_variant: Literal["teachers", "td_self"] = documented(
        "teachers", "where an acl team's difficulty comes from: 'teachers' (the K-fold teachers' errors, as cmcl) "
        "or 'td_self' (the learner's own |δ| on the row)")
    priority_sharing: Literal["per_agent"] = documented(
        "per_agent", "one sampler per agent (A3); A3's option 'team_mean' (one sampler per team on the team's mean "
        "ĉ and ρ̂) is refused here, not implemented",
        rule=rule("must be 'per_agent' (A3's 'team_mean' is not implemented)", lambda v: v == "per_agent"))
    actor_batch: Literal["rule", "uniform"] = documented(
        "rule", "the rows the actor step trains on: 'rule' = the critic's minibatch, drawn by the team's rule; "
        "'uniform' = a minibatch of its own drawn uniformly from the buffer, apart from the critic's, without IS "
        "weights (actor prioritised replay, Saglam et al. 2023; issue 36); accepted and without effect on maddpg, "
        "whose critic's minibatch is already uniform")
    priority: PriorityConfig = documented(
        factory=PriorityConfig, meaning="the team's sampling settings: the [teams.<team>.priority] table")

    def __post_init__(self) -> None:
        check_fields(self, "team")

    def effective_alpha(self) -> float:
        """α_s this team samples with: its priority.alpha, else its algorithm's default (DEFAULT_ALPHA, from the
        registry)."""
        alpha = self.priority.alpha
        return DEFAULT_ALPHA[self.algorithm] if alpha is None else alpha

    @property
    def uniform_actor(self) -> bool:
        """Whether this team's actor trains on a uniform minibatch of its own (actor_batch = "uniform" under a rule
        that does not already draw the critic's uniformly)."""
        return self.actor_batch == "uniform" and REGISTRY[self.algorithm].prioritised

    @property
    def needs(self):
        """What this team's sampling rule needs (cmcl.algorithms.Needs: teachers, icm, learner scores)."""
        return REGISTRY[self.algorithm].needs(self)

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
        return self.eta if REGISTRY[self.algorithm].uses_eta else 0.0

    @property
    def importance_weights(self) -> bool:
        """Whether IS weights correct this team's critic loss (its algorithm's default unless is_correction)."""
        return REGISTRY[self.algorithm].importance_weights if self.is_correction is None else self.is_correction


@dataclass(frozen=True)
class RunConfig:
    """Budget, seed, output and bookkeeping of one run."""

    episodes: int = documented(20000, "training budget", unit="episodes", rule=AT_LEAST_1)
    dir: str = documented("runs/default", "the run directory (config, metrics, checkpoints, evaluation; "
                          "cmcl.io.rundir)", unit="path", rule=rule("must be a non-empty path", bool))
    seed: int = documented(0, "seed of the run's random generators (worlds, networks, sampling)", rule=AT_LEAST_0)
    log_every: int = documented(10, "episodes between progress lines / metric rows", unit="episodes",
                                rule=AT_LEAST_1)
    checkpoint_every: int = documented(500, "episodes between checkpoints (0: only at the end)", unit="episodes",
                                       rule=AT_LEAST_0)
    smoothing_window: int = documented(100, "window of the curves' and progress lines' moving averages",
                                       unit="episodes", rule=AT_LEAST_1)
    stop_coverage: float = documented(0.0, "stop early once the moving average (over smoothing_window episodes) "
                                      "of final-step coverage reaches this (spread only; 0: off, train all "
                                      "run.episodes)", unit="fraction of landmarks", rule=PROBABILITY)
    max_seconds: float = documented(0.0, "wall-clock budget of training, inline and in the service (0: none)",
                                    unit="seconds", rule=FINITE_AT_LEAST_0)
    stop_progress: float = documented(
        0.0, "stop early once learning stops progressing (cmcl.learning_progress): the relative change of the mean "
        "critic loss between consecutive windows of progress_window episodes stays below this for "
        "progress_patience windows (0: off). The agent-count curriculum (python -m cmcl stages) ends its stages "
        "by it", unit="relative change", rule=FINITE_AT_LEAST_0)
    progress_window: int = documented(500, "episodes per learning-progress window (run.stop_progress)",
                                      unit="episodes", rule=AT_LEAST_1)
    progress_patience: int = documented(3, "consecutive windows below stop_progress that end the run",
                                        unit="windows", rule=AT_LEAST_1)
    init_from: str = documented(
        "", "a run directory whose newest policy initialises this new run's actors and critics "
        "(cmcl.learners.warm_start; same network shapes required); '' = random initial weights. A resumed run "
        "ignores it (its checkpoint wins)", unit="path")
    carry_replay: bool = documented(
        False, "with init_from, also start with that run's replay rows (its newest checkpoint's buffer), padded to "
        "this run's agent count (cmcl.replay.agent_padding: absent agents zero and masked per row), so that the "
        "buffer holds rows of both counts (issue 22's agent curriculum: `python -m cmcl stages ... --set "
        "run.carry_replay=true`). Needs maddpg.networks = 'entity', task spread and algorithms maddpg or per; "
        "either runner. Off: an empty buffer")

    def __post_init__(self) -> None:
        check_fields(self, "run")


@dataclass(frozen=True)
class ServiceConfig:
    """Distributed service (services/), read by the service runner only: actor counts, per-call work, rate-limiter
    slack, CPUs, metrics."""

    rollout_workers: int = documented(1, "rollout worker actors, each stepping env.num_envs worlds",
                                      unit="actors", rule=AT_LEAST_1)
    teacher_actors: int = documented(
        0, "actors sharing the K teacher folds: K = one fold each, 1 = all folds stacked in one actor; 0 = "
        "automatic: K when the cluster has at least 2K CPUs, else 1 (on 2 cores one stacked actor is 1.4x faster "
        "than K); placement policy: services.placement.teacher_groups", unit="actors", rule=AT_LEAST_0)
    updates_per_call: int = documented(16, "learner updates per learner call (batches sampled per replay call)",
                                       unit="updates", rule=AT_LEAST_1)
    fit_steps_per_call: int = documented(8, "teacher / ICM fit steps per call", unit="fit steps", rule=AT_LEAST_1)
    score_rows_per_call: int = documented(1024, "rows a teacher / the ICM rescores per call", unit="rows",
                                          rule=AT_LEAST_1)
    slack_updates: int = documented(256, "how far updates may run ahead of / behind the env-step ratio (the rate "
                                    "limiter's slack)", unit="updates", rule=AT_LEAST_1)
    call_timeout_s: float = documented(300.0, "a call in flight longer than this marks its actor hung: killed, "
                                       "restarted (0: off)", unit="seconds", rule=rule("must be >= 0 (0: off)",
                                                                                      lambda v: v >= 0))
    replay_log_fsync: bool = documented(False, "fsync every replay-log append (survives power loss; flush-only "
                                        "survives crashes)")
    recompute_every: int = documented(0, "inserts between bulk priority recomputes (0: one episode of every "
                                      "worker)", unit="inserts", rule=AT_LEAST_0)
    checkpoint_every_s: float = documented(
        60.0, "seconds between checkpoints of every role (and one at the end, and one on a graceful stop): bounds "
        "the learning a hard crash loses; measured cost at 60 s: bench/checkpoint_cadence.py", unit="seconds",
        rule=POSITIVE)
    max_restarts: int = documented(3, "restarts Ray may make of one actor after it dies", unit="restarts",
                                   rule=AT_LEAST_0)
    rollout_cpus: float = documented(0.25, "CPUs Ray reserves for each rollout worker", unit="CPUs",
                                     rule=POSITIVE)
    learner_cpus: float = documented(0.5, "CPUs Ray reserves for the learner", unit="CPUs", rule=POSITIVE)
    teacher_cpus: float = documented(0.1, "CPUs Ray reserves for each teacher actor", unit="CPUs", rule=POSITIVE)
    icm_cpus: float = documented(0.1, "CPUs Ray reserves for the ICM actor", unit="CPUs", rule=POSITIVE)
    replay_cpus: float = documented(0.25, "CPUs Ray reserves for the replay server", unit="CPUs", rule=POSITIVE)
    rollout_resource: str = documented(
        "", "a custom Ray resource the rollout workers require (0.01 of it each), to keep them on the nodes that "
        "advertise it (e.g. `ray start --resources='{\"rollout\": 100}'` on CPU worker nodes); '' = any node",
        rule=rule("must be a Ray resource name ([A-Za-z0-9_-]+)",
                  lambda v: v == "" or v.replace("_", "").replace("-", "").isalnum()))
    metrics_port: int = documented(9100, "port of the Prometheus metrics endpoint (0: pick a free port)",
                                   unit="TCP port", rule=rule("must lie in [0, 65535]", lambda v: 0 <= v <= 65535))
    metrics_host: str = documented("127.0.0.1", "address the metrics endpoint listens on", unit="host")

    def __post_init__(self) -> None:
        check_fields(self, "service")

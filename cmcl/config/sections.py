"""The section dataclasses of a run configuration: one frozen, self-validating dataclass per component.

Every field has the paper's Table 1 value or the resolution of ../shared/ALGORITHM.md §5 as its default. Each
`__post_init__` checks ranges and raises `ConfigError` naming the full key (e.g. ``maddpg.gamma``) and the value.
The whole run (`Config`) is in cmcl.config.experiment, the [env] section (`EnvConfig`) in cmcl.config.env; TOML
loading in cmcl.config.toml_io; the value checks (`ConfigError`, `_require`, ...) in cmcl.config.checks.
"""

from __future__ import annotations

import math
import typing
from dataclasses import dataclass
from typing import Literal

from cmcl.config.checks import ConfigError, _positive, _probability, _require
from cmcl.replay.sampling import ALGORITHMS, AlgorithmName

TaskName = Literal["spread", "tag"]
NetworkKind = Literal["per_agent", "shared", "entity"]
NETWORK_KINDS: tuple[str, ...] = typing.get_args(NetworkKind)
TASKS: tuple[str, ...] = typing.get_args(TaskName)
TASK_TEAMS = {"spread": ("agent",), "tag": ("predator", "prey")}  # teams of each task, in agent order
# α_s of eq. 20 when nothing sets it (ALGORITHM.md A8, revised 2026-12): "proportional to the K-fold priority" for
# ACL and CMCL, Schaul's proportional-variant 0.6 for PER-MADDPG; MADDPG samples uniformly (α unused)
DEFAULT_ALPHA = {"maddpg": 1.0, "per": 0.6, "acl": 1.0, "cmcl": 1.0}
__all__ = ["ALGORITHMS", "DEFAULT_ALPHA", "TASKS", "TASK_TEAMS", "ConfigError",
           "CurriculumConfig", "ICMConfig",
           "MADDPGConfig", "ReplayConfig", "RunConfig", "ServiceConfig", "TeacherConfig", "TeamConfig"]


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

    actor_lr: float = 1e-3
    critic_lr: float = 1e-3
    gamma: float = 0.99
    tau: float = 0.01
    hidden: int = 64
    batch_size: int = 128
    grad_clip: float = 0.5
    exploration_std: float = 0.1  # Gaussian noise on tanh actions
    discrete: bool = False  # Gumbel-softmax variant (A17)
    warmup: int = 3840  # transitions before the first update: batch × episode length (A18)
    # world steps (one step of one world = one transition) per learner update; 16 solves navigation fastest in
    # wall clock (docs/LEARNING.md, python -m experiments run schedule); the paper presets (configs/paper/)
    # use 1 (A18)
    update_every: int = 16
    # one actor and one critic network for all agents, each with its own first-layer bias (an agent-id embedding,
    # cmcl.learners.nets); for N = 8 / 16 (bench/scale.py). False = the paper's per-agent networks
    share_parameters: bool = False
    # the networks' kind (issue 22): "per_agent" (one actor and critic per agent, the paper's), "shared" (the same
    # as share_parameters = true) or "entity" (one attention actor and one permutation-invariant critic for all
    # agents over the observation's entities, a parameter count independent of N: cmcl.learners.entity_nets;
    # built-in tasks only). Unset: "shared" if share_parameters else "per_agent"
    networks: NetworkKind | None = None
    # how every entity network of the run (learner, teachers.networks and icm.networks = "entity") pools its
    # entities: "attention" (one head from the agent's own embedding, plus a mean), "mean" (the mean only, about
    # half the cost per update) or "relational" ("attention" after one round of self-attention among the
    # entities, so that a landmark's embedding can say another agent holds it: cmcl.learners.entity_nets)
    entity_pool: Literal["attention", "mean", "relational"] = "attention"

    def __post_init__(self) -> None:
        _check_networks("maddpg", self.networks, self.share_parameters)
        for name in ("actor_lr", "critic_lr", "grad_clip"):
            _positive(f"maddpg.{name}", getattr(self, name))
        _probability("maddpg.gamma", self.gamma)
        _probability("maddpg.tau", self.tau, open_low=True)
        for name in ("hidden", "batch_size", "update_every"):
            _require(getattr(self, name) >= 1, f"maddpg.{name}", getattr(self, name), "must be >= 1")
        _require(self.warmup >= 0, "maddpg.warmup", self.warmup, "must be >= 0")
        _require(self.exploration_std >= 0, "maddpg.exploration_std", self.exploration_std, "must be >= 0")

    @property
    def network_kind(self) -> str:
        """The networks built: maddpg.networks, or what share_parameters implies when it is unset."""
        return _network_kind(self.networks, self.share_parameters)


@dataclass(frozen=True)
class ReplayConfig:
    """Replay storage and prioritized sampling (ALGORITHM.md §3.1, §3.6)."""

    capacity: int = 5000
    # sampling exponent α_s of eq. 20 for every team (A8). None (default): each team's own `teams.<t>.alpha`, else
    # the per-algorithm default DEFAULT_ALPHA (1 for acl / cmcl, 0.6 for per). A number here applies to every team
    # that does not set its own; precedence: teams.<t>.alpha > replay.alpha > DEFAULT_ALPHA[algorithm]
    alpha: float | None = None
    priority_eps: float = 1e-6  # ε_p floor
    beta_is_start: float = 0.4  # PER importance-sampling exponent, annealed linearly …
    beta_is_end: float = 1.0  # … to this value over training
    backend: Literal["cdf", "sumtree"] = "cdf"

    def __post_init__(self) -> None:
        _require(self.capacity >= 1, "replay.capacity", self.capacity, "must be >= 1")
        _require(self.alpha is None or (self.alpha >= 0 and math.isfinite(self.alpha)), "replay.alpha", self.alpha,
                 "must be a finite number >= 0 (or unset: the per-algorithm default)")
        _positive("replay.priority_eps", self.priority_eps)
        _probability("replay.beta_is_start", self.beta_is_start)
        _probability("replay.beta_is_end", self.beta_is_end)


@dataclass(frozen=True)
class CurriculumConfig:
    """Curriculum factor λ schedule (ALGORITHM.md §3.7)."""

    lam0: float = 0.1
    lam_max: float = 1.0
    # Δλ per post-warm-up env step; 0 means "reach lam_max at half of run.episodes" (3e-6 for 20k episodes).
    stride: float = 0.0
    kind: Literal["linear", "multiplicative"] = "linear"

    def __post_init__(self) -> None:
        _probability("curriculum.lam_max", self.lam_max, open_low=True)
        _require(0 < self.lam0 <= self.lam_max, "curriculum.lam0", self.lam0, "must lie in (0, lam_max]")
        _require(self.stride >= 0, "curriculum.stride", self.stride, "must be >= 0")


@dataclass(frozen=True)
class TeacherConfig:
    """K-fold teacher critics (ALGORITHM.md §3.2, A13, A14)."""

    num_folds: int = 5
    batch_size: int = 128
    lr: float = 1e-3
    hidden: int = 64
    # rows rescored per learner update (every never-scored row, then the oldest scores, cmcl.replay.scoring): the
    # whole 5000-row buffer every ~39 updates; the paper preset's 167 = all of it every 30 updates (§3.8)
    rescore_rows_per_update: int = 128
    # "shared": one fold batch per fold serves every agent's teacher of that fold (one target pass; the service's
    # layout); "per_agent": each (agent, fold) teacher draws its own batch (§3.2 literally, A x the target cost)
    fit_batch: Literal["shared", "per_agent"] = "shared"
    # ĉ of §3.3 (A1, revised 2026-12): "rank" = percentile over the buffer, rank/(|D|−1) (λ reads as a difficulty
    # percentile, so KP excludes rows while λ < 0.5); "max" = min(1, c / max c), the earlier default, which puts the
    # heavy-tailed c at ĉ ≈ 0.05 (every row on KP's rising branch: near-uniform sampling, ESS >= 0.9)
    difficulty_norm: Literal["max", "rank"] = "rank"
    # sampling controls of the acl / cmcl teams (issue 21), to tell "the curriculum helps" from "sampling is just
    # different": "none" = the method; "reversed" = anti-curriculum, ĉ -> 1 − ĉ before KP (eq. 12); "permuted" =
    # each recompute, every curriculum agent's priority column is shuffled across the buffer's rows by a seeded
    # permutation (cmcl.replay.priority.permute_priorities): the same multiset of probabilities, hence the same
    # ESS, carrying no information about the rows. Uniform and PER agents are unaffected
    difficulty_transform: Literal["none", "permuted", "reversed"] = "none"
    difficulty_error: Literal["squared", "abs"] = "squared"
    # teacher fit steps per learner update, inline and in the service (its rate limiter); §3.8 has 1, the
    # default 0.5 halves the teachers' cost (CMCL update cost vs MADDPG: bench/learner_throughput.py)
    steps_per_update: float = 0.5
    # one teacher network per fold for all agents, each agent with its own first-layer bias (cmcl.learners.nets,
    # grouped sharing); the folds stay separate. For N = 8 / 16 (bench/scale.py). False = per-(agent, fold) networks
    share_parameters: bool = False
    # the teachers' kind, as maddpg.networks: "entity" = one entity critic (cmcl.learners.entity_nets) per fold for
    # all agents, its parameter count independent of N; unset: "shared" if share_parameters else "per_agent"
    networks: NetworkKind | None = None

    def __post_init__(self) -> None:
        _check_networks("teachers", self.networks, self.share_parameters)
        _require(self.num_folds >= 2, "teachers.num_folds", self.num_folds, "must be >= 2")
        for name in ("batch_size", "hidden", "rescore_rows_per_update"):
            _require(getattr(self, name) >= 1, f"teachers.{name}", getattr(self, name), "must be >= 1")
        _positive("teachers.lr", self.lr)
        _positive("teachers.steps_per_update", self.steps_per_update)

    @property
    def network_kind(self) -> str:
        """The teachers' networks: teachers.networks, or what share_parameters implies when it is unset."""
        return _network_kind(self.networks, self.share_parameters)


@dataclass(frozen=True)
class ICMConfig:
    """Intrinsic curiosity module (ALGORITHM.md §3.4–3.5, A5–A7)."""

    feature_dim: int = 32
    hidden: int = 64
    beta_forward: float = 0.2
    lr: float = 1e-3
    batch_size: int = 128
    cp_input: Literal["std", "raw"] = "std"
    intrinsic_reward_coef: float = 0.0  # A6: curiosity feeds priority only
    steps_per_update: float = 0.5  # ICM steps per learner update, inline and in the service (§3.8: 1)
    # "per_agent": one encoder, inverse and forward model per curiosity agent; "entity": one of each for all of
    # them, the encoder over the observation's entities (cmcl.learners.entity_nets), a size independent of N
    networks: Literal["per_agent", "entity"] = "per_agent"

    def __post_init__(self) -> None:
        for name in ("feature_dim", "hidden", "batch_size"):
            _require(getattr(self, name) >= 1, f"icm.{name}", getattr(self, name), "must be >= 1")
        _probability("icm.beta_forward", self.beta_forward)
        _positive("icm.lr", self.lr)
        _require(self.intrinsic_reward_coef >= 0, "icm.intrinsic_reward_coef", self.intrinsic_reward_coef,
                 "must be >= 0")
        _positive("icm.steps_per_update", self.steps_per_update)


@dataclass(frozen=True)
class TeamConfig:
    """Which algorithm a team of agents learns with (ALGORITHM.md §5)."""

    algorithm: AlgorithmName = "cmcl"
    eta: float = 0.5  # curiosity weight in CI (A15); forced to 0 for acl
    # this team's sampling exponent α_s (eq. 20, A8); None: replay.alpha if set, else DEFAULT_ALPHA[algorithm]
    # (1 for acl / cmcl, 0.6 for per); see `effective_alpha`
    alpha: float | None = None
    is_correction: bool | None = None  # None: on for per, off for acl/cmcl (A9)
    acl_variant: Literal["teachers", "td_self"] = "teachers"
    # one sampler per agent (A3); A3's option "team_mean" (one sampler per team on the team's mean ĉ and ρ̂) is
    # refused here, not implemented
    priority_sharing: Literal["per_agent"] = "per_agent"

    def __post_init__(self) -> None:
        _require(self.eta >= 0 and math.isfinite(self.eta), "team.eta", self.eta, "must be >= 0")
        _require(self.priority_sharing == "per_agent", "team.priority_sharing", self.priority_sharing,
                 "must be 'per_agent' (A3's 'team_mean' is not implemented)")
        _require(self.alpha is None or (self.alpha >= 0 and math.isfinite(self.alpha)), "team.alpha", self.alpha,
                 "must be a finite number >= 0 (or unset: the per-algorithm default)")

    def effective_alpha(self, run_alpha: float | None = None) -> float:
        """α_s this team samples with: its own `alpha`, else `run_alpha` (replay.alpha), else DEFAULT_ALPHA."""
        if self.alpha is not None:
            return self.alpha
        return DEFAULT_ALPHA[self.algorithm] if run_alpha is None else run_alpha

    @property
    def uses_teachers(self) -> bool:
        """True when this team's priority needs K-fold teacher difficulty scores."""
        return self.algorithm == "cmcl" or (self.algorithm == "acl" and self.acl_variant == "teachers")

    @property
    def uses_icm(self) -> bool:
        """True when this team's priority needs curiosity scores."""
        return self.algorithm == "cmcl" and self.eta > 0

    @property
    def effective_eta(self) -> float:
        """η as used in CI: 0 for every algorithm but CMCL."""
        return self.eta if self.algorithm == "cmcl" else 0.0

    @property
    def importance_weights(self) -> bool:
        """Whether IS weights correct this team's critic loss."""
        return (self.algorithm == "per") if self.is_correction is None else self.is_correction


@dataclass(frozen=True)
class RunConfig:
    """Budget, seed, output and bookkeeping of one run."""

    episodes: int = 20000
    dir: str = "runs/default"
    seed: int = 0
    log_every: int = 10  # episodes between progress lines / metric rows
    checkpoint_every: int = 500  # episodes between checkpoints (0: only at the end)
    smoothing_window: int = 100  # episodes, for curves and moving averages
    # stop early once the moving average (over smoothing_window episodes) of final-step coverage reaches this
    # (spread only; 0: off, train all run.episodes)
    stop_coverage: float = 0.0
    max_seconds: float = 0.0  # wall-clock budget of training, inline and in the service (0: none)
    # stop early once learning stops progressing (cmcl.learning_progress): the relative change of the mean critic
    # loss between consecutive windows of progress_window episodes stays below this for progress_patience windows
    # (0: off). The agent-count curriculum (python -m cmcl stages) ends its stages by it
    stop_progress: float = 0.0
    progress_window: int = 500  # episodes per learning-progress window
    progress_patience: int = 3  # consecutive windows below stop_progress that end the run
    # a run directory whose newest policy initialises this new run's actors and critics (cmcl.learners.warm_start;
    # same network shapes required); "" = random initial weights. A resumed run ignores it (its checkpoint wins)
    init_from: str = ""
    # with init_from, also start with that run's replay rows (its newest checkpoint's buffer), padded to this run's
    # agent count (cmcl.replay.agent_padding: absent agents zero and masked per row), so that the buffer holds rows
    # of both counts (issue 22's agent curriculum: `python -m cmcl stages ... --set run.carry_replay=true`). Needs
    # maddpg.networks = "entity", task spread and algorithms maddpg or per; either runner. Off: an empty buffer
    carry_replay: bool = False

    def __post_init__(self) -> None:
        _require(self.episodes >= 1, "run.episodes", self.episodes, "must be >= 1")
        _probability("run.stop_coverage", self.stop_coverage)
        _require(self.max_seconds >= 0 and math.isfinite(self.max_seconds), "run.max_seconds", self.max_seconds,
                 "must be a finite number >= 0")
        _require(bool(self.dir), "run.dir", self.dir, "must be a non-empty path")
        _require(self.seed >= 0, "run.seed", self.seed, "must be >= 0")
        _require(self.stop_progress >= 0 and math.isfinite(self.stop_progress), "run.stop_progress",
                 self.stop_progress, "must be a finite number >= 0")
        for name in ("log_every", "smoothing_window", "progress_window", "progress_patience"):
            _require(getattr(self, name) >= 1, f"run.{name}", getattr(self, name), "must be >= 1")
        _require(self.checkpoint_every >= 0, "run.checkpoint_every", self.checkpoint_every, "must be >= 0")


@dataclass(frozen=True)
class ServiceConfig:
    """Distributed service (services/): actor counts, per-call work, rate-limiter slack, CPUs, metrics."""

    rollout_workers: int = 1
    # actors sharing the K teacher folds: K = one fold each, 1 = all folds stacked in one actor; 0 = automatic:
    # K when the cluster has at least 2K CPUs, else 1 (on 2 cores one stacked actor is 1.4x faster than K)
    teacher_actors: int = 0  # placement policy: services.placement.teacher_groups
    updates_per_call: int = 16  # learner updates per learner call (batches sampled per replay call)
    fit_steps_per_call: int = 8  # teacher / ICM fit steps per call
    score_rows_per_call: int = 1024  # rows a teacher / the ICM rescores per call
    slack_updates: int = 256  # how far updates may run ahead of / behind the env-step ratio
    call_timeout_s: float = 300.0  # a call in flight longer than this marks its actor hung: killed, restarted (0: off)
    replay_log_fsync: bool = False  # fsync every replay-log append (survives power loss; flush-only survives crashes)
    recompute_every: int = 0  # inserts between bulk priority recomputes (0: one episode of every worker)
    # seconds between checkpoints of every role (and one at the end, and one on a graceful stop): bounds the
    # learning a hard crash loses; measured cost at 60 s: bench/checkpoint_cadence.py
    checkpoint_every_s: float = 60.0
    max_restarts: int = 3  # per actor
    rollout_cpus: float = 0.25
    learner_cpus: float = 0.5
    teacher_cpus: float = 0.1
    icm_cpus: float = 0.1
    replay_cpus: float = 0.25
    # a custom Ray resource the rollout workers require (0.01 of it each), to keep them on the nodes that
    # advertise it (e.g. `ray start --resources='{"rollout": 100}'` on CPU worker nodes); "" = any node
    rollout_resource: str = ""
    metrics_port: int = 9100  # 0: pick a free port
    metrics_host: str = "127.0.0.1"

    def __post_init__(self) -> None:
        for name in ("rollout_workers", "updates_per_call", "fit_steps_per_call", "score_rows_per_call",
                     "slack_updates"):
            _require(getattr(self, name) >= 1, f"service.{name}", getattr(self, name), "must be >= 1")
        _require(self.recompute_every >= 0, "service.recompute_every", self.recompute_every, "must be >= 0")
        _require(self.teacher_actors >= 0, "service.teacher_actors", self.teacher_actors, "must be >= 0")
        _require(self.max_restarts >= 0, "service.max_restarts", self.max_restarts, "must be >= 0")
        _require(self.call_timeout_s >= 0, "service.call_timeout_s", self.call_timeout_s, "must be >= 0 (0: off)")
        for name in ("rollout_cpus", "learner_cpus", "teacher_cpus", "icm_cpus", "replay_cpus"):
            _positive(f"service.{name}", getattr(self, name))
        _positive("service.checkpoint_every_s", self.checkpoint_every_s)
        _require(self.rollout_resource == "" or self.rollout_resource.replace("_", "").replace("-", "").isalnum(),
                 "service.rollout_resource", self.rollout_resource, "must be a Ray resource name ([A-Za-z0-9_-]+)")
        _require(0 <= self.metrics_port <= 65535, "service.metrics_port", self.metrics_port, "must lie in [0, 65535]")



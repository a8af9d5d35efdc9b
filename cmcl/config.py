"""Typed, validated run configuration: one frozen dataclass per component, loaded from TOML.

Where it sits: every entry point (`cmcl.loop`, `cmcl.evaluate`, `services.launch`) builds a `Config` with
`load_config(path, overrides)` and hands each component its section. Defaults are the paper's Table 1 values
and the resolutions of ../shared/ALGORITHM.md §5 (each [R] choice is an option here with that default).

Errors: any unknown key, wrong type or out-of-range value raises `ConfigError` naming the full key
(e.g. ``maddpg.gamma``) and the offending value.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import types
import typing
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

ALGORITHMS = ("maddpg", "per", "acl", "cmcl")
TASKS = ("spread", "tag")
TASK_TEAMS = {"spread": ("agent",), "tag": ("predator", "prey")}


class ConfigError(ValueError):
    """A configuration key is unknown, of the wrong type, or out of range."""


def _require(ok: bool, key: str, value: Any, why: str) -> None:
    """Raise ConfigError('<key> <why>, got <value>') unless ok."""
    if not ok:
        raise ConfigError(f"{key} {why}, got {value!r}")


def _positive(key: str, value: float) -> None:
    _require(value > 0 and math.isfinite(value), key, value, "must be a finite number > 0")


def _probability(key: str, value: float, *, open_low: bool = False) -> None:
    ok = (0 < value <= 1) if open_low else (0 <= value <= 1)
    _require(ok, key, value, "must lie in (0, 1]" if open_low else "must lie in [0, 1]")


@dataclass(frozen=True)
class EnvConfig:
    """Sparse MPE world (ALGORITHM.md §6)."""

    task: Literal["spread", "tag"] = "spread"
    num_agents: int = 4  # spread: agents = landmarks
    num_predators: int = 2  # tag; calibrated (ALGORITHM.md §6.2 "calibration", bench/tag_calibration.py)
    num_prey: int = 2  # tag
    num_obstacles: int = 3  # tag
    episode_length: int = 30  # steps per episode [P]
    agent_radius: float = 0.05  # spread agents [R]; option 0.15 (simple_spread)
    obstacle_radius: float = 0.1  # tag obstacles [R]; option 0.2 (MPE "large")
    predator_radius: float = 0.0375  # tag, calibrated [R]: MPE's 0.075 x 0.5 (capture at r_pred + r_prey)
    prey_radius: float = 0.025  # tag, calibrated [R]: MPE's 0.05 x 0.5
    # tag D1 (§6.2, revised): False = each (predator, prey) pair in contact pays +5 to that predator only;
    # True = every predator receives +5 per pair in contact (MPE simple_tag's shared team reward)
    tag_shared_reward: bool = False
    # spread: False = each agent receives its own C1 + C2 (ALGORITHM.md §6.1, revised: the team sum hides who
    # earned what from each agent's critic and blocks learning); True = every agent receives the team sum
    shared_reward: bool = False
    num_envs: int = 16  # worlds stepped at once by the batched twin (inline loop / rollout worker)

    def __post_init__(self) -> None:
        for name in ("num_agents", "num_predators", "num_prey", "episode_length", "num_envs"):
            _require(getattr(self, name) >= 1, f"env.{name}", getattr(self, name), "must be >= 1")
        _require(self.num_obstacles >= 0, "env.num_obstacles", self.num_obstacles, "must be >= 0")
        _positive("env.agent_radius", self.agent_radius)
        _positive("env.obstacle_radius", self.obstacle_radius)
        _positive("env.predator_radius", self.predator_radius)
        _positive("env.prey_radius", self.prey_radius)


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
    # wall clock (README, bench/time_to_solve.py --grid schedule); the paper presets (configs/paper/) use 1 (A18)
    update_every: int = 16

    def __post_init__(self) -> None:
        for name in ("actor_lr", "critic_lr", "grad_clip"):
            _positive(f"maddpg.{name}", getattr(self, name))
        _probability("maddpg.gamma", self.gamma)
        _probability("maddpg.tau", self.tau, open_low=True)
        for name in ("hidden", "batch_size", "update_every"):
            _require(getattr(self, name) >= 1, f"maddpg.{name}", getattr(self, name), "must be >= 1")
        _require(self.warmup >= 0, "maddpg.warmup", self.warmup, "must be >= 0")
        _require(self.exploration_std >= 0, "maddpg.exploration_std", self.exploration_std, "must be >= 0")


@dataclass(frozen=True)
class ReplayConfig:
    """Replay storage and prioritized sampling (ALGORITHM.md §3.1, §3.6)."""

    capacity: int = 5000
    alpha: float = 0.6  # sampling exponent α_s (A8)
    priority_eps: float = 1e-6  # ε_p floor
    beta_is_start: float = 0.4  # PER importance-sampling exponent, annealed linearly …
    beta_is_end: float = 1.0  # … to this value over training
    backend: Literal["cdf", "sumtree"] = "cdf"

    def __post_init__(self) -> None:
        _require(self.capacity >= 1, "replay.capacity", self.capacity, "must be >= 1")
        _require(self.alpha >= 0, "replay.alpha", self.alpha, "must be >= 0")
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
    # rows rescored per learner update (never-scored rows first, then a rolling cursor over the buffer): the
    # whole 5000-row buffer every ~39 updates; the paper preset's 167 = all of it every 30 updates (§3.8)
    rescore_rows_per_update: int = 128
    # "shared": one fold batch per fold serves every agent's teacher of that fold (one target pass; the service's
    # layout); "per_agent": each (agent, fold) teacher draws its own batch (§3.2 literally, A x the target cost)
    fit_batch: Literal["shared", "per_agent"] = "shared"
    difficulty_norm: Literal["max", "rank"] = "max"
    difficulty_error: Literal["squared", "abs"] = "squared"
    # teacher fit steps per learner update, inline and in the service (its rate limiter); §3.8 has 1, the
    # default 0.5 halves the teachers' cost (CMCL update cost vs MADDPG: bench/learner_throughput.py)
    steps_per_update: float = 0.5

    def __post_init__(self) -> None:
        _require(self.num_folds >= 2, "teachers.num_folds", self.num_folds, "must be >= 2")
        for name in ("batch_size", "hidden", "rescore_rows_per_update"):
            _require(getattr(self, name) >= 1, f"teachers.{name}", getattr(self, name), "must be >= 1")
        _positive("teachers.lr", self.lr)
        _positive("teachers.steps_per_update", self.steps_per_update)


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

    algorithm: Literal["maddpg", "per", "acl", "cmcl"] = "cmcl"
    eta: float = 0.5  # curiosity weight in CI (A15); forced to 0 for acl
    is_correction: bool | None = None  # None: on for per, off for acl/cmcl (A9)
    acl_variant: Literal["teachers", "td_self"] = "teachers"
    priority_sharing: Literal["per_agent", "team_mean"] = "per_agent"

    def __post_init__(self) -> None:
        _require(self.eta >= 0 and math.isfinite(self.eta), "team.eta", self.eta, "must be >= 0")

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

    def __post_init__(self) -> None:
        _require(self.episodes >= 1, "run.episodes", self.episodes, "must be >= 1")
        _probability("run.stop_coverage", self.stop_coverage)
        _require(self.max_seconds >= 0 and math.isfinite(self.max_seconds), "run.max_seconds", self.max_seconds,
                 "must be a finite number >= 0")
        _require(bool(self.dir), "run.dir", self.dir, "must be a non-empty path")
        _require(self.seed >= 0, "run.seed", self.seed, "must be >= 0")
        for name in ("log_every", "smoothing_window"):
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
    recompute_every: int = 0  # inserts between bulk priority recomputes (0: one episode of every worker)
    checkpoint_every_s: float = 300.0  # seconds between service checkpoints (and one at the end)
    max_restarts: int = 3  # per actor
    rollout_cpus: float = 0.25
    learner_cpus: float = 0.5
    teacher_cpus: float = 0.1
    icm_cpus: float = 0.1
    replay_cpus: float = 0.25
    metrics_port: int = 9100  # 0: pick a free port
    metrics_host: str = "127.0.0.1"

    def __post_init__(self) -> None:
        for name in ("rollout_workers", "updates_per_call", "fit_steps_per_call", "score_rows_per_call",
                     "slack_updates"):
            _require(getattr(self, name) >= 1, f"service.{name}", getattr(self, name), "must be >= 1")
        _require(self.recompute_every >= 0, "service.recompute_every", self.recompute_every, "must be >= 0")
        _require(self.teacher_actors >= 0, "service.teacher_actors", self.teacher_actors, "must be >= 0")
        _require(self.max_restarts >= 0, "service.max_restarts", self.max_restarts, "must be >= 0")
        for name in ("rollout_cpus", "learner_cpus", "teacher_cpus", "icm_cpus", "replay_cpus"):
            _positive(f"service.{name}", getattr(self, name))
        _positive("service.checkpoint_every_s", self.checkpoint_every_s)
        _require(0 <= self.metrics_port <= 65535, "service.metrics_port", self.metrics_port, "must lie in [0, 65535]")


@dataclass(frozen=True)
class Config:
    """The whole run: one section per component plus one TeamConfig per team of the task."""

    env: EnvConfig = field(default_factory=EnvConfig)
    maddpg: MADDPGConfig = field(default_factory=MADDPGConfig)
    replay: ReplayConfig = field(default_factory=ReplayConfig)
    curriculum: CurriculumConfig = field(default_factory=CurriculumConfig)
    teachers: TeacherConfig = field(default_factory=TeacherConfig)
    icm: ICMConfig = field(default_factory=ICMConfig)
    run: RunConfig = field(default_factory=RunConfig)
    service: ServiceConfig = field(default_factory=ServiceConfig)
    teams: dict[str, TeamConfig] = field(default_factory=lambda: {"agent": TeamConfig()})

    def __post_init__(self) -> None:
        expected = TASK_TEAMS[self.env.task]
        _require(set(self.teams) == set(expected), "teams", sorted(self.teams),
                 f"must name exactly the teams of task {self.env.task!r}: {list(expected)}")
        ordered = {name: self.teams[name] for name in expected}
        object.__setattr__(self, "teams", ordered)
        _require(self.maddpg.warmup <= self.replay.capacity, "maddpg.warmup", self.maddpg.warmup,
                 f"must not exceed replay.capacity ({self.replay.capacity})")
        _require(self.maddpg.batch_size <= max(self.maddpg.warmup, 1) or self.maddpg.warmup == 0,
                 "maddpg.batch_size", self.maddpg.batch_size, f"must not exceed maddpg.warmup ({self.maddpg.warmup})")

    @property
    def total_env_steps(self) -> int:
        """Environment steps of the whole run (per world): episodes × episode length."""
        return self.run.episodes * self.env.episode_length

    def curriculum_stride(self) -> float:
        """Δλ per post-warm-up env step: the configured stride, or λ_max reached at half of training."""
        if self.curriculum.stride > 0:
            return self.curriculum.stride
        half = max(1, self.total_env_steps // 2)
        return (self.curriculum.lam_max - self.curriculum.lam0) / half

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dict (TOML/JSON friendly; None values dropped)."""
        return _drop_none(dataclasses.asdict(self))


def _drop_none(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _drop_none(v) for k, v in value.items() if v is not None}
    return value


_SECTIONS = {f.name: f for f in dataclasses.fields(Config) if f.name != "teams"}


def _coerce(key: str, value: Any, hint: Any) -> Any:
    """Check `value` against the type hint `hint` (bool, int, float, str, Literal, Optional)."""
    origin = typing.get_origin(hint)
    if origin is Literal:
        choices = typing.get_args(hint)
        _require(value in choices, key, value, f"must be one of {list(choices)}")
        return value
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(hint)
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _coerce(key, value, inner[0])
    if hint is bool:
        _require(isinstance(value, bool), key, value, "must be true or false")
        return value
    if hint is int:
        _require(isinstance(value, int) and not isinstance(value, bool), key, value, "must be an integer")
        return value
    if hint is float:
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        _require(ok, key, value, "must be a number")
        return float(value)
    if hint is str:
        _require(isinstance(value, str), key, value, "must be a string")
        return value
    raise ConfigError(f"{key}: unsupported field type {hint!r}")


def _build(cls: type, data: Mapping[str, Any], prefix: str) -> Any:
    """Build dataclass `cls` from `data`, rejecting unknown keys and values of the wrong type."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{prefix} must be a table, got {data!r}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(f"unknown key {prefix}.{unknown[0]} (known: {sorted(names)})")
    kwargs = {k: _coerce(f"{prefix}.{k}", v, hints[k]) for k, v in data.items()}
    try:
        return cls(**kwargs)
    except ConfigError as err:
        # __post_init__ messages use the section name; re-prefix team checks with the team's path.
        msg = str(err)
        raise ConfigError(msg.replace("team.", f"{prefix}.", 1) if msg.startswith("team.") else msg) from None


def config_from_dict(data: Mapping[str, Any]) -> Config:
    """Build and validate a Config from a nested mapping (as parsed from TOML)."""
    unknown = sorted(set(data) - set(_SECTIONS) - {"teams"})
    if unknown:
        raise ConfigError(f"unknown section {unknown[0]!r} (known: {sorted([*_SECTIONS, 'teams'])})")
    sections = {name: _build(f.default_factory, data.get(name, {}), name) for name, f in _SECTIONS.items()}
    teams_data = data.get("teams")
    if teams_data is None:
        teams_data = {name: {} for name in TASK_TEAMS[sections["env"].task]}
    if not isinstance(teams_data, Mapping):
        raise ConfigError(f"teams must be a table of team tables, got {teams_data!r}")
    teams = {name: _build(TeamConfig, spec, f"teams.{name}") for name, spec in teams_data.items()}
    return Config(**sections, teams=teams)


def preset(algorithm: str, task: str = "spread", opponent: str = "maddpg") -> Config:
    """Config of one of the four compared algorithms (ALGORITHM.md §5).

    For `task="tag"` the predators learn with `algorithm` and the prey with `opponent` (Fig. 12: MADDPG prey).
    """
    _require(algorithm in ALGORITHMS, "algorithm", algorithm, f"must be one of {list(ALGORITHMS)}")
    _require(opponent in ALGORITHMS, "opponent", opponent, f"must be one of {list(ALGORITHMS)}")
    _require(task in TASKS, "env.task", task, f"must be one of {list(TASKS)}")
    if task == "spread":
        teams = {"agent": {"algorithm": algorithm}}
    else:
        teams = {"predator": {"algorithm": algorithm}, "prey": {"algorithm": opponent}}
    return config_from_dict({"env": {"task": task}, "teams": teams})


def parse_override(text: str) -> tuple[list[str], Any]:
    """Parse 'section.key=value' (value in TOML syntax; bare words are strings) into (path, value)."""
    if "=" not in text:
        raise ConfigError(f"override must look like section.key=value, got {text!r}")
    dotted, raw = text.split("=", 1)
    path = [part.strip() for part in dotted.strip().split(".")]
    if len(path) < 2 or not all(path):
        raise ConfigError(f"override key must be section.key, got {dotted!r}")
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    return path, value


def apply_overrides(data: dict[str, Any], overrides: Iterable[str]) -> dict[str, Any]:
    """Return a copy of nested `data` with each 'a.b.c=value' override set."""
    result = _deep_copy(data)
    for text in overrides:
        path, value = parse_override(text)
        node = result
        for part in path[:-1]:
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise ConfigError(f"override {text!r}: {part} is not a table")
            node = child
        node[path[-1]] = value
    return result


def _deep_copy(data: Mapping[str, Any]) -> dict[str, Any]:
    return {k: _deep_copy(v) if isinstance(v, Mapping) else v for k, v in data.items()}


def load_config(path: str | Path | None = None, overrides: Iterable[str] = ()) -> Config:
    """Load a TOML file (or the defaults when `path` is None) and apply `--set` overrides."""
    data: dict[str, Any] = {}
    if path is not None:
        path = Path(path)
        if not path.is_file():
            raise ConfigError(f"config file {str(path)!r} does not exist")
        try:
            data = tomllib.loads(path.read_text())
        except tomllib.TOMLDecodeError as err:
            raise ConfigError(f"config file {str(path)!r} is not valid TOML: {err}") from None
    return config_from_dict(apply_overrides(data, overrides))


def dump_toml(config: Config) -> str:
    """Render a Config as TOML text that `load_config` reads back to an equal Config."""
    data = config.to_dict()
    lines: list[str] = []
    for section, values in data.items():
        if section == "teams":
            continue
        lines.append(f"[{section}]")
        lines.extend(f"{k} = {_toml_value(v)}" for k, v in values.items())
        lines.append("")
    for team, values in data["teams"].items():
        lines.append(f"[teams.{team}]")
        lines.extend(f"{k} = {_toml_value(v)}" for k, v in values.items())
        lines.append("")
    return "\n".join(lines)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    return repr(value)

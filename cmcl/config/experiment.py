"""The whole run: `Config` (one section per component plus one TeamConfig per team), derived quantities, presets.

Loading a Config from TOML or a nested mapping is cmcl.config.toml_io; the sections are cmcl.config.learning,
cmcl.config.teams, cmcl.config.run_and_service and cmcl.config.env.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from cmcl.config.checks import _require
from cmcl.config.env import TASK_TEAMS, TASKS, EnvConfig, TaskCurriculumConfig
from cmcl.config.learning import CurriculumConfig, ICMConfig, MADDPGConfig, ReplayConfig, TeacherConfig
from cmcl.config.run_and_service import RunConfig, ServiceConfig
from cmcl.config.teams import TeamConfig
from cmcl.learners.entity.holder_rules import SEATED_RADIUS
from cmcl.replay.curriculum import default_stride
from cmcl.replay.registry import ALGORITHMS, REGISTRY


@dataclass(frozen=True)
class Config:
    """The whole run: one section per component plus one TeamConfig per team of the task."""

    env: EnvConfig = field(default_factory=EnvConfig)
    task_curriculum: TaskCurriculumConfig = field(default_factory=TaskCurriculumConfig)
    maddpg: MADDPGConfig = field(default_factory=MADDPGConfig)
    replay: ReplayConfig = field(default_factory=ReplayConfig)
    curriculum: CurriculumConfig = field(default_factory=CurriculumConfig)
    teachers: TeacherConfig = field(default_factory=TeacherConfig)
    icm: ICMConfig = field(default_factory=ICMConfig)
    run: RunConfig = field(default_factory=RunConfig)
    service: ServiceConfig = field(default_factory=ServiceConfig)
    teams: dict[str, TeamConfig] = field(default_factory=lambda: {"agent": TeamConfig()})

    def __post_init__(self) -> None:
        if self.env.factory:  # the env's own teams are only known once it is built: cmcl.system.agent_layout checks
            _require(bool(self.teams), "teams", self.teams, "must name at least one team")
            _require(not self.maddpg.discrete, "maddpg.discrete", True,
                     "must be false with env.factory (it selects the built-in tasks' 5-way action; a factory "
                     "environment with Discrete action spaces gets Gumbel-softmax actors without it)")
        else:
            expected = TASK_TEAMS[self.env.task]
            _require(set(self.teams) == set(expected), "teams", sorted(self.teams),
                     f"must name exactly the teams of task {self.env.task!r}: {list(expected)}")
            object.__setattr__(self, "teams", {name: self.teams[name] for name in expected})
        self.task_curriculum.check_world(self.env)
        _require(self.maddpg.warmup <= self.replay.capacity, "maddpg.warmup", self.maddpg.warmup,
                 f"must not exceed replay.capacity ({self.replay.capacity})")
        _require(self.maddpg.batch_size <= max(self.maddpg.warmup, 1) or self.maddpg.warmup == 0,
                 "maddpg.batch_size", self.maddpg.batch_size, f"must not exceed maddpg.warmup ({self.maddpg.warmup})")
        if self.run.carry_replay:
            self._check_carry_replay()
        if self.maddpg.assignment_loss > 0:
            self._check_assignment_loss()
        _require(not self.maddpg.entity_holder or (self.env.task == "spread" and not self.env.factory),
                 "maddpg.entity_holder", True, "needs env.task = 'spread' (a landmark's holder margin; env.task "
                 f"= {self.env.task!r}" + (" with env.factory" if self.env.factory else "") + " here)")
        _require(self.maddpg.holder_rule == "nearest" or self.env.spread.cover_radius == SEATED_RADIUS,
                 "maddpg.holder_rule", self.maddpg.holder_rule, f"needs env.cover_radius = {SEATED_RADIUS} "
                 f"(an agent within it of a landmark sits there; env.cover_radius = {self.env.spread.cover_radius} "
                 "here)")
        if self.run.stop_progress > 0 and self.run.progress_signal == "coverage":
            has_coverage = bool(self.env.coverage_key) if self.env.factory else self.env.task == "spread"
            _require(has_coverage, "run.progress_signal", "coverage",
                     "needs episodes with a coverage (env.task = 'spread', or env.coverage_key with env.factory) "
                     f"when run.stop_progress > 0; env.task = {self.env.task!r}"
                     + (" with env.factory" if self.env.factory else "")
                     + ": set run.progress_signal = 'normalised_td' (or 'critic_loss')")

    def _check_carry_replay(self) -> None:
        """run.carry_replay's needs (cmcl.replay.agent_padding): rows of fewer agents padded into the navigation
        layout, read by the entity networks, which alone mask absent agents; the teachers, the ICM and ACL's online
        critic score rows without the mask, so only MADDPG's uniform and PER's sampling may draw them."""
        why = "needs {} ({} here)"
        _require(self.maddpg.networks == "entity", "run.carry_replay", True,
                 why.format("maddpg.networks = 'entity' (networks whose parameters do not depend on N)",
                            f"maddpg.networks = {self.maddpg.networks!r}"))
        _require(self.env.task == "spread" and not self.env.factory, "run.carry_replay", True,
                 why.format("env.task = 'spread' (its rows of fewer agents are padded into its entity layout)",
                            f"env.task = {self.env.task!r}" + (" with env.factory" if self.env.factory else "")))
        unmasked = sorted({team.algorithm for team in self.teams.values() if not team.rule.masks_absent_agents})
        masking = [name for name, rule in REGISTRY.items() if rule.masks_absent_agents]
        _require(not unmasked, "run.carry_replay", True,
                 why.format(f"every team's rule to mask absent agents, one of {masking} (the teachers, the ICM and "
                            "ACL's online critic do not mask them when they score rows)", f"{unmasked}"))

    def _check_assignment_loss(self) -> None:
        """maddpg.assignment_loss's needs (cmcl.learners.entity.assignment): the entity actor's attention over the
        entity slots (entity networks, a pool with attention) and landmarks to assign (the navigation task)."""
        key, value, why = "maddpg.assignment_loss", self.maddpg.assignment_loss, "> 0 needs {} ({} here)"
        _require(self.maddpg.networks == "entity", key, value,
                 why.format("maddpg.networks = 'entity'", f"maddpg.networks = {self.maddpg.networks!r}"))
        _require(self.maddpg.entity_pool != "mean", key, value,
                 why.format("an attention to supervise, maddpg.entity_pool = 'attention' or 'relational'",
                            "maddpg.entity_pool = 'mean'"))
        _require(self.maddpg.entity_nearest == 0, key, value,
                 why.format("every entity slot, maddpg.entity_nearest = 0 (its attention is over the picked ones, "
                            "reordered per row)", f"maddpg.entity_nearest = {self.maddpg.entity_nearest}"))
        _require(self.env.task == "spread" and not self.env.factory, key, value,
                 why.format("a task with landmarks, env.task = 'spread'",
                            f"env.task = {self.env.task!r}" + (" with env.factory" if self.env.factory else "")))

    @property
    def trains_icm(self) -> bool:
        """Whether the run has an ICM role: a team's sampling rule needs curiosity (CMCL's CP), or ρ is a reward
        (icm.intrinsic_reward_coef > 0: every agent is then a curiosity agent, cmcl.system.agent_layout)."""
        return self.icm.intrinsic_reward_coef > 0 or any(t.uses_icm for t in self.teams.values())

    @property
    def total_env_steps(self) -> int:
        """Environment steps of the whole run (per world): episodes × episode length."""
        return self.run.episodes * self.env.episode_length

    def curriculum_stride(self) -> float:
        """Δλ per post-warm-up env step: the configured stride, or λ_max reached at half of training."""
        if self.curriculum.stride > 0:
            return self.curriculum.stride
        return default_stride(self.total_env_steps, self.curriculum.lam0, self.curriculum.lam_max)

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dict (TOML/JSON friendly; None values dropped) with the keys a TOML file uses (the [env]
        world parameters flat, EnvConfig.to_dict; each team's rule options as keys of its table);
        `config_from_dict` reads it back to an equal Config."""
        teams = {name: {**{k: v for k, v in dataclasses.asdict(team).items() if k != "options"},
                        **dataclasses.asdict(team.options)} for name, team in self.teams.items()}
        return _drop_none({**dataclasses.asdict(self), "env": self.env.to_dict(), "teams": teams})


def _drop_none(value: Any) -> Any:
    """`value` with every None dropped from its (nested) dicts."""
    if isinstance(value, dict):
        return {k: _drop_none(v) for k, v in value.items() if v is not None}
    return value


def preset(algorithm: str, task: str = "spread", opponent: str = "maddpg") -> Config:
    """Config of one of the four compared algorithms (ALGORITHM.md §5), every other value at its default.

    For `task="tag"` the predators learn with `algorithm` and the prey with `opponent` (Fig. 12: MADDPG prey).
    """
    _require(algorithm in ALGORITHMS, "algorithm", algorithm, f"must be one of {list(ALGORITHMS)}")
    _require(opponent in ALGORITHMS, "opponent", opponent, f"must be one of {list(ALGORITHMS)}")
    _require(task in TASKS, "env.task", task, f"must be one of {list(TASKS)}")
    if task == "spread":
        teams = {"agent": TeamConfig(algorithm=algorithm)}
    else:
        teams = {"predator": TeamConfig(algorithm=algorithm), "prey": TeamConfig(algorithm=opponent)}
    return Config(env=EnvConfig(task=task), teams=teams)

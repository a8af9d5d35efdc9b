"""The [env] section of a run configuration: which world the agents live in (ALGORITHM.md §6).

Where it sits: `EnvConfig` holds the task's world parameters as the env package's own dataclasses
(`spread: SpreadParams`, `tag: TagParams`, cmcl.envs.params: their one home, with units and range checks), and
cmcl.system hands `EnvConfig.world` to the task's batched twin and PettingZoo env as it is. The built-in tasks
(`TASKS`) and each one's teams in agent order (`TASK_TEAMS`) are named here.

TOML keys: the world's fields are written flat in [env], as before (`[env] agent_radius = 0.05`,
`num_predators = 2`, `--set env.cover_radius=0.075`): each key is the field's name, except that a `TagParams`
field whose name `SpreadParams` also has takes the prefix `tag_` (`env.tag_shared_reward`). `WORLD_KEYS` is that
mapping, derived from the two dataclasses; cmcl.config.toml_io reads it, `EnvConfig.to_dict` writes it.
"""

from __future__ import annotations

import dataclasses
import re
import typing
from dataclasses import dataclass
from typing import Any, Literal

from cmcl.config.checks import AT_LEAST_1, PROBABILITY, ConfigError, _require, check_fields, rule
from cmcl.envs.params import EPISODE_LENGTH, SpreadParams, TagParams
from cmcl.envs.twins import TWINS
from cmcl.envs.world_settings import setting_of
from cmcl.field_docs import documented

TaskName = Literal["spread", "tag"]
TASKS: tuple[str, ...] = typing.get_args(TaskName)
TASK_TEAMS = {"spread": ("agent",), "tag": ("predator", "prey")}  # teams of each task, in agent order
FACTORY_PATTERN = re.compile(r"^[A-Za-z_][\w.]*:[A-Za-z_][\w.]*$")  # "package.module:callable"


@dataclass(frozen=True)
class WorldKey:
    """Where a flat [env] key lives: field `name` of EnvConfig's `task` attribute ("spread" -> SpreadParams)."""

    task: TaskName
    name: str


def _world_keys() -> dict[str, WorldKey]:
    """Flat [env] key -> its field: every SpreadParams field by its name, every TagParams field by its name or,
    when SpreadParams has the same name, by "tag_" + name."""
    keys = {f.name: WorldKey("spread", f.name) for f in dataclasses.fields(SpreadParams)}
    for f in dataclasses.fields(TagParams):
        keys["tag_" + f.name if f.name in keys else f.name] = WorldKey("tag", f.name)
    return keys


WORLD_KEYS: dict[str, WorldKey] = _world_keys()


def _individual_reward_spread() -> SpreadParams:
    """The navigation world of a run: SpreadParams' defaults with each agent receiving its own C1 + C2
    (ALGORITHM.md §6.1, revised: the team sum hides who earned what from each agent's critic and blocks
    learning); `env.shared_reward = true` gives every agent the team sum (the PettingZoo env's default)."""
    return SpreadParams(shared_reward=False)


@dataclass(frozen=True)
class EnvConfig:
    """Sparse MPE world (ALGORITHM.md §6): the task, its world parameters, the episode length and the batch."""

    task: TaskName = documented("spread", "the built-in task: 'spread' (sparse cooperative navigation, §6.1) or "
                                "'tag' (sparse predator-prey, §6.2); its world is set by the world keys below")
    episode_length: int = documented(EPISODE_LENGTH, "steps per episode [P]", unit="steps", rule=AT_LEAST_1)
    num_envs: int = documented(16, "worlds stepped at once by the batched twin (inline loop / rollout worker)",
                               unit="worlds", rule=AT_LEAST_1)
    spread: SpreadParams = documented(
        meaning="the navigation world (cmcl.envs.params.SpreadParams), used when task = 'spread'; TOML: its fields "
        "flat in [env], see WORLD_KEYS. The run's default pays each agent its own reward (shared_reward = false)",
        factory=_individual_reward_spread, rule=rule("must be a SpreadParams", lambda v: isinstance(v, SpreadParams)))
    tag: TagParams = documented(
        meaning="the predator-prey world (cmcl.envs.params.TagParams, §6.2's calibrated world), used when task = "
        "'tag'; TOML: its fields flat in [env]; env.tag_shared_reward = true pays every predator +5 per pair in "
        "contact", factory=TagParams, rule=rule("must be a TagParams", lambda v: isinstance(v, TagParams)))
    factory: str = documented(
        "", "your own environment (docs/OWN_ENVIRONMENT.md): 'package.module:callable' returning a PettingZoo "
        "ParallelEnv, called with env.factory_kwargs; '' = the built-in env.task. Its episodes end when the env ends "
        "them or at env.episode_length steps, whichever comes first (env.episode_length set nowhere: the env's own "
        "max_cycles / max_steps / spec.max_episode_steps, else 30); the world keys are then unused",
        rule=rule("must look like 'package.module:callable' (or be empty for the built-in task)",
                  lambda v: v == "" or bool(FACTORY_PATTERN.match(v))))
    factory_kwargs: dict[str, Any] = documented(meaning="keyword arguments of env.factory (a table of scalars)",
                                                factory=dict)
    team_of: dict[str, str] = documented(meaning="agent id -> team, for env.factory; default: the id's prefix "
                                         "(adversary_0 -> adversary)", factory=dict)
    success_key: str = documented("", "the env's per-agent `info` key read as episode success: the mean over agents "
                                  "of each one's last value, an agent that left early counting with its own ('': none)")
    coverage_key: str = documented("", "likewise for coverage in [0, 1] (what run.stop_coverage watches)")
    twin: bool = documented(
        False, "step env.factory's batched numpy twin (cmcl.envs.twins: the sparse navigation worlds') instead of "
        "env.num_envs copies of its ParallelEnv; the same dynamics, rewards and success on the same seed and actions "
        "(tests/test_sparse_tasks.py), vectorised; needs an env.factory that has one")

    def __post_init__(self) -> None:
        check_fields(self, "env")
        _require(not self.twin or self.factory in TWINS, "env.twin", self.twin,
                 f"needs an env.factory that has a batched twin ({sorted(TWINS)}); env.factory = {self.factory!r}")

    @property
    def world(self) -> SpreadParams | TagParams:
        """The world parameters of `task`, as its batched twin and PettingZoo env take them."""
        return self.spread if self.task == "spread" else self.tag

    def to_dict(self) -> dict[str, Any]:
        """The section as its flat TOML keys (the world's fields by their WORLD_KEYS names); dicts are copies."""
        world = {key: getattr(getattr(self, home.task), home.name) for key, home in WORLD_KEYS.items()}
        rest = {k: v for k, v in dataclasses.asdict(self).items() if k not in TASKS}
        return {"task": rest.pop("task"), **world, **rest}


Advance = Literal["success", "coverage", "progress", "fixed"]
ADVANCES: tuple[str, ...] = typing.get_args(Advance)


@dataclass(frozen=True)
class TaskCurriculumConfig:
    """[task_curriculum]: a curriculum over one of the world's own settings (cmcl.rollout.task_curriculum; the
    generalisation of the agent-count stages, cmcl.run.agent_stages). Each rollout worker gives each of its worlds, at
    the world's episode boundaries, the value of the current stage (or, with `mix`, of an earlier one), and moves to the
    next stage when the advance rule fires on its own episodes of the current stage. Off while `param` is ''."""

    param: str = documented(
        "", "the world setting the stages change (cmcl.envs.world_settings: navigation's spawn_scale, cover_radius, "
        "gate; Push-Box's push_cells; Pass's switch_reach), '' = no task curriculum; needs env.factory of a sparse "
        "task")
    stages: tuple[float, ...] = documented(
        meaning="its values, easiest first (the last is the target task: the source's value); at least 2",
        factory=tuple, unit="the setting's own")
    advance: Advance = documented(
        "success", "when a stage ends: 'success' / 'coverage' when the moving average of the training success / "
        "coverage of its last `window` episodes reaches `level`; 'progress' when that average has risen above 0 and "
        "then changes by less than `level` from one window of `window` episodes to the next (a plateau); 'fixed' "
        "after every `window` episodes (the control arm: the same stages on a fixed schedule)")
    level: float = documented(0.8, "the advance rule's threshold (success / coverage: a rate in [0, 1]; progress: "
                              "the change of that rate between windows)", rule=PROBABILITY)
    window: int = documented(200, "episodes per window of the advance rule (episodes of the current stage, per "
                             "rollout worker)", unit="episodes", rule=AT_LEAST_1)
    mix: float = documented(0.0, "the share of episodes drawn at a uniformly chosen earlier stage (VACL's solved set "
                            "beside its active one); 0 = every episode at the current stage", rule=PROBABILITY)

    def __post_init__(self) -> None:
        check_fields(self, "task_curriculum")

    @property
    def enabled(self) -> bool:
        return bool(self.param)

    def check_world(self, env: EnvConfig) -> None:
        """Refuse, naming the key and the value, a param the task of `env` cannot set or a stage out of its range."""
        if not self.enabled:
            _require(not self.stages, "task_curriculum.stages", list(self.stages), "needs task_curriculum.param")
            return
        try:
            setting = setting_of(env.factory, self.param, "task_curriculum.param")
            _require(len(self.stages) >= 2, "task_curriculum.stages", list(self.stages),
                     "must hold at least 2 values, easiest first")
            for i, value in enumerate(self.stages):
                setting.check(value, f"task_curriculum.stages[{i}]")
        except ValueError as err:
            raise ConfigError(str(err)) from None

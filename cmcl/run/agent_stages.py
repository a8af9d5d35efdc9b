"""A curriculum over the number of agents: train N_1 < N_2 < ... agents in turn, each stage starting from the
networks the stage before it ended with (EPC, Long et al. 2020, and SPMARL, Zhao et al. 2025).

    python -m cmcl stages --agents 2 4 8 --config configs/spread_maddpg.toml --set maddpg.networks=entity \
        [--stage-episodes 3000 3000 14000] [--set run.stop_progress=0.02] [--runner inline|service]

Each stage is an ordinary run of either runner in `<run.dir>/n<N>` (`env.num_agents = N`, `run.init_from` = the
stage before), so `python -m cmcl evaluate` and `resume` work on any stage. When a stage ends:
- **fixed schedule**: after its own budget, `--stage-episodes` (default: run.episodes for every stage);
- **learning progress**: with `run.stop_progress > 0`, as soon as the learning progress of `run.progress_signal`
  stays below it for `run.progress_patience` windows (cmcl.progress.learning; by default the change of the mean
  training coverage between 500-episode windows, 0.02 measured to end a flat stage and not a learning one), or at
  its budget. The last stage, the target task, always trains its whole budget.
Only networks whose shapes do not depend on the number of agents can be carried from one N to the next; any other
setting is refused before the first stage starts, naming the tensor and its shapes at both N.

Rerunning the same command goes on where it stopped: a stage whose summary says it ended (budget, solved, plateau) is
kept, a stage with a checkpoint is resumed, a stage folder without one starts over.

Each stage starts with an empty replay buffer, unless `--set run.carry_replay=true` (entity networks, MADDPG or PER
sampling, either runner): then every stage after the first also starts with the rows of the stage before (its newest
checkpoint's buffer, cmcl.run.carried_replay), padded to its N with the absent agents masked
(cmcl.replay.agent_padding), so that its buffer holds rows of both counts until its own rows overwrite them.
"""

from __future__ import annotations

import dataclasses
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from cmcl.config import Config, ConfigError, load_config
from cmcl.run.flags import RunRequest
from cmcl.run.rundir import RunDirectory

FINISHED = ("budget", "solved", "plateau")  # a stage's summary "ended" values that mean it is done


@dataclass(frozen=True)
class Stage:
    """One stage: its agent count, run folder, the overrides that make it (on top of the user's) and its budget."""

    num_agents: int
    run_dir: Path
    overrides: tuple[str, ...]
    last: bool


def plan_stages(config: Config, agents: Sequence[int], stage_episodes: Sequence[int] | None) -> list[Stage]:
    """The stages of `agents` (strictly increasing, >= 1) under the root `config.run.dir`. Raises ConfigError naming
    the flag and the value for a bad plan."""
    agents = [int(n) for n in agents]
    if not agents or any(n < 1 for n in agents) or any(b <= a for a, b in zip(agents, agents[1:], strict=False)):
        raise ConfigError(f"--agents must be agent counts >= 1 in increasing order, got {agents}")
    if stage_episodes is not None and len(stage_episodes) != len(agents):
        raise ConfigError(f"--stage-episodes needs one budget per stage ({len(agents)}), got {list(stage_episodes)}")
    if stage_episodes is not None and any(int(e) < 1 for e in stage_episodes):
        raise ConfigError(f"--stage-episodes must be >= 1, got {list(stage_episodes)}")
    if config.run.init_from:
        raise ConfigError(f"run.init_from={config.run.init_from!r}: the stages set it themselves (each stage starts "
                          "from the one before); start the first stage's own run with init_from instead")
    if config.env.task != "spread" or config.env.factory:
        raise ConfigError(f"env.task={config.env.task!r}: agent-count stages are built for navigation (spread), "
                          "whose N agents cover N landmarks")
    root, stages, previous = Path(config.run.dir), [], None
    for k, n in enumerate(agents):
        last = k == len(agents) - 1
        sets = [f"env.num_agents={n}", f"run.dir={root / f'n{n}'}"]
        if previous is not None:
            sets.append(f"run.init_from={previous}")
        elif config.run.carry_replay:
            sets.append("run.carry_replay=false")  # the first stage has no stage before it to carry rows from
        if stage_episodes is not None:
            sets.append(f"run.episodes={int(stage_episodes[k])}")
        if last:
            sets.append("run.stop_progress=0.0")  # the target task trains its whole budget
        stages.append(Stage(n, root / f"n{n}", tuple(sets), last))
        previous = root / f"n{n}"
    return stages


def check_networks_carry(low: Config, high: Config) -> None:
    """Refuse, before anything trains, networks whose parameter shapes change with the agent count (`low` and `high`:
    the first and the last stage's configs): their weights cannot go from one stage to the next. Raises ConfigError
    naming the tensor and its shapes at both counts (the warm start's own shape check, cmcl.learners.state_check)."""
    from cmcl.learners.state_check import require_same_shapes
    from cmcl.run.warm_start import WARM_PARTS
    from cmcl.system import build_maddpg, layout_of

    first, last = (build_maddpg(config, layout_of(config), seed=0) for config in (low, high))
    try:
        require_same_shapes("maddpg", {part: getattr(last, part) for part in WARM_PARTS},
                            {part: getattr(first, part).state_dict() for part in WARM_PARTS},
                            f"agent counts (the first stage at N = {low.env.spread.num_agents}, the last at N = "
                            f"{high.env.spread.num_agents}); per-agent and flat-input networks grow with N")
    except ValueError as err:
        raise ConfigError(f"agent-count stages need networks whose shapes do not depend on the number of agents: "
                          f"{err}") from err


def stage_request(base: RunRequest, stage: Stage) -> RunRequest:
    """The run request of `stage`: resume its folder when it holds a checkpoint, else a new run there (over a folder
    without a checkpoint, which holds nothing worth keeping). Stages before the last skip the end-of-run evaluation."""
    no_eval = base.no_eval or not stage.last
    if stage.run_dir.exists() and RunDirectory.open(stage.run_dir).runners():
        return dataclasses.replace(base, config_file=None, overrides=(), resume_dir=str(stage.run_dir),
                                   overwrite=False, no_eval=no_eval)
    return dataclasses.replace(base, overrides=(*base.overrides, *stage.overrides), resume_dir=None, overwrite=True,
                               no_eval=no_eval)


def stage_finished(stage: Stage) -> bool:
    """The stage's run ended on its own (budget, solved, plateau), not stopped by a signal or unfinished."""
    return RunDirectory(stage.run_dir).summary().get("ended") in FINISHED


def run_stages(base: RunRequest, agents: Sequence[int], stage_episodes: Sequence[int] | None,
               train: Callable[[RunRequest], int], say: Callable[[str], None] = print) -> int:
    """Train the stages in turn with `train` (a runner entry); returns 0 when every stage is done, else the exit
    code of the stage that stopped (2: refused, 130 / 143: stopped by a signal, resumable by the same command)."""
    try:
        if base.overwrite:
            raise ConfigError("--overwrite: the stages go on from where they stopped; to start over, name another "
                              "run.dir")
        config = load_config(base.config_file, base.config_overrides())
        stages = plan_stages(config, agents, stage_episodes)
        low, high = (load_config(base.config_file, (*base.config_overrides(), f"env.num_agents={s.num_agents}"))
                     for s in (stages[0], stages[-1]))
        check_networks_carry(low, high)
    except (ConfigError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    for stage in stages:
        if stage_finished(stage):
            say(f"stage N = {stage.num_agents}: done earlier ({stage.run_dir})")
            continue
        say(f"stage N = {stage.num_agents}: {stage.run_dir}")
        code = train(stage_request(base, stage))
        if code != 0:
            say(f"stage N = {stage.num_agents} did not finish (exit {code}); the same command goes on from there")
            return code
        summary = RunDirectory(stage.run_dir).summary()
        say(f"stage N = {stage.num_agents} ended ({summary.get('ended')}) at episode {summary.get('episodes')}")
    return 0

"""A task curriculum over one of the world's own settings: stages of a setting's value, easiest first, advanced by
a scale-free signal of the training episodes (or on a fixed schedule, the control arm).

    [task_curriculum]
    param = "spawn_scale"          # cmcl.envs.world_settings: what the env's setter accepts
    stages = [0.1, 0.3, 0.6, 1.0]  # easiest first; the last is the target task
    advance = "success"            # "success" | "coverage" | "progress" | "fixed"
    level = 0.8
    window = 200                   # episodes
    mix = 0.2                      # share of episodes at an earlier stage

Where it sits: the rollout worker (services/roles/rollout.py, the same role object under both runners) owns one
`TaskCurriculum` and calls it at its worlds' episode boundaries; the stage each finished episode was played at goes
into the episode rows of metrics.jsonl (`task_stage`) and the progress row, and the curriculum's state is saved and
loaded with the rollout role's checkpoint (`state` / `load_state`). Each rollout worker advances on its own
episodes (the service's several workers each keep their own stage).

How a stage is applied: a world's setting changes only at its next reset (`set_world_settings` of the batched env,
cmcl.envs.world_settings), so every episode runs at one value. When a world's episode ends, the world restarts at
the stage drawn for it at its previous boundary, and the stage of its next episode is drawn now: the current stage,
or with probability `mix` a uniformly chosen earlier one (VACL's solved set beside its active set). When the stage
advances, every world's next episode is redrawn at the new stage.

The advance rules (`advance`), over the episodes played at the current stage only:
* success / coverage: the mean of the last `window` episodes' success (every landmark covered / the task solved at
  the end) or final coverage reaches `level` (a rate in [0, 1], whatever the task's reward scale);
* progress: at the end of each window of `window` episodes, the learning progress is the change of that window's
  mean success from the window before; the stage advances when the mean has risen above 0 and the change is below
  `level` (learning at this stage has levelled off);
* fixed: after `window` episodes (the same stages on a fixed episode schedule, without the signal's information).
The last stage is never left.
"""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np

from cmcl.config.env import TaskCurriculumConfig


class TaskCurriculum:
    """The stage of one rollout worker's worlds and the advance rule's window; see the module docstring."""

    def __init__(self, config: TaskCurriculumConfig, num_envs: int, rng: np.random.Generator) -> None:
        self.config, self.rng = config, rng
        self.values = np.asarray(config.stages, np.float64)
        self.stage = 0
        self.window: deque[float] = deque(maxlen=config.window)  # the current stage's last episodes' signal
        self.counted = 0  # episodes of the current stage seen so far
        self.previous: float | None = None  # progress: the mean of the stage's window before the last
        self.advanced_at: list[int] = []  # episodes (of this worker, every stage) at which each advance happened
        self.episodes = 0
        self.world_stage = np.zeros(num_envs, np.int64)  # stage of each world's running episode
        self.next_stage = np.zeros(num_envs, np.int64)  # stage of each world's next episode

    @property
    def key(self) -> str:
        """The episode statistic the rule reads."""
        return "coverage" if self.config.advance == "coverage" else "success"

    def start(self, env: Any) -> None:
        """Before the worlds' first reset: every world's first episode at the current stage, the next ones drawn."""
        everyone = np.arange(len(self.world_stage))
        self.world_stage[:] = self.stage
        env.set_world_settings(self.config.param, everyone, self.values[self.world_stage])
        self._redraw(env, everyone)

    def _redraw(self, env: Any, idx: np.ndarray) -> None:
        """Draw the stage of the next episode of the worlds idx int64[M] and hand the env their values."""
        stages = np.full(len(idx), self.stage, np.int64)
        if self.stage > 0 and self.config.mix > 0:
            earlier = self.rng.random(len(idx)) < self.config.mix
            stages[earlier] = self.rng.integers(0, self.stage, int(earlier.sum()))
        self.next_stage[idx] = stages
        env.set_world_settings(self.config.param, idx, self.values[stages])

    def episodes_ended(self, env: Any, ended: np.ndarray, episode: dict[str, np.ndarray]) -> np.ndarray:
        """After a step of the (auto-resetting) env in which the worlds `ended` bool[B] finished their episodes
        (`episode`: the env's info["episode"] over them, in index order): record them, advance if the rule fires,
        and set the worlds' next stages. Returns the stage each finished episode was played at, int64[M]."""
        idx = np.flatnonzero(ended)
        played = self.world_stage[idx].copy()
        self.world_stage[idx] = self.next_stage[idx]  # they restarted at the stage drawn for them before
        advanced = self.record(played, np.asarray(episode.get(self.key, np.zeros(len(idx))), np.float64))
        self._redraw(env, np.arange(len(self.world_stage)) if advanced else idx)
        return played

    def record(self, played: np.ndarray, signal: np.ndarray) -> bool:
        """Feed the episodes played at stages `played` int64[M] with their signal float64[M] (success or coverage
        in [0, 1]) to the advance rule; returns whether the stage advanced."""
        advanced = False
        for stage, value in zip(played.tolist(), signal.tolist(), strict=True):
            self.episodes += 1
            if stage != self.stage or self.stage == len(self.values) - 1:
                continue
            self.window.append(float(value))
            self.counted += 1
            if self._fires():
                self.stage += 1
                self.window.clear()
                self.counted, self.previous = 0, None
                self.advanced_at.append(self.episodes)
                advanced = True
        return advanced

    def _fires(self) -> bool:
        """Whether the advance rule fires after the episode just recorded."""
        c, full = self.config, len(self.window) == self.config.window
        if c.advance == "fixed":
            return self.counted >= c.window
        if c.advance in ("success", "coverage"):
            return full and float(np.mean(self.window)) >= c.level
        if self.counted % c.window:  # progress: judged at the end of each window
            return False
        mean, previous = float(np.mean(self.window)), self.previous
        self.previous = mean
        return previous is not None and mean > 0 and abs(mean - previous) < c.level

    def state(self) -> dict[str, Any]:
        """JSON-safe state (the rollout role's checkpoint): stage, the rule's window, counters, the draw's rng."""
        return {"stage": self.stage, "window": list(self.window), "counted": self.counted, "previous": self.previous,
                "advanced_at": list(self.advanced_at), "episodes": self.episodes,
                "rng": self.rng.bit_generator.state, "stages": self.values.tolist(), "param": self.config.param}

    def load_state(self, state: dict[str, Any]) -> None:
        """Go on from `state` (of `state()`); refused, naming both, when its param or stages are not this config's.
        Call `start` afterwards (the worlds start new episodes at the restored stage)."""
        if state["param"] != self.config.param or list(state["stages"]) != self.values.tolist():
            raise ValueError(f"task_curriculum: the checkpoint's param {state['param']!r} with stages "
                             f"{state['stages']} is not this run's {self.config.param!r} with {self.values.tolist()}")
        self.stage, self.counted, self.previous = int(state["stage"]), int(state["counted"]), state["previous"]
        self.window = deque((float(v) for v in state["window"]), maxlen=self.config.window)
        self.advanced_at, self.episodes = [int(e) for e in state["advanced_at"]], int(state["episodes"])
        self.rng.bit_generator.state = state["rng"]

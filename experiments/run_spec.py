"""What one learning run of a grid is (`Run`: its id, task, algorithms, seed, budget and overrides, and the record its
summary stores), and ROOT, the checkout the experiments run in.

Where it sits: the grid registry (experiments.grids) makes Runs, the runner (experiments.runner) trains them, the
measures (experiments.measures) and provenance (experiments.provenance) describe them; this module imports nothing
of the experiments, so each of those reads it without importing the registry.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Run:
    """One learning run of a grid. id: its name (summary file, run folder); budget: episodes; config: a file
    under configs/ (default `<task>_<algorithm>.toml`); sets: extra `--set SECTION.KEY=VALUE` overrides; source:
    the id of a finished run whose first `budget` episodes this one reads instead of training (a prefix
    reference); mode: the runner; stop_coverage / max_seconds: early stops (None: train the whole budget); env: a
    name of experiments.own_envs.OWN_ENVS (task "own_env": no config file, the defaults and `sets`); stages: the
    agent counts of an agent-count curriculum, trained by `python -m cmcl stages` into <run folder>/n<N>, measured on
    its last stage, with the earlier stages' episodes and seconds added to its costs."""

    id: str
    grid: str
    task: Literal["spread", "tag", "own_env"]
    algorithm: str
    prey_algorithm: str | None
    seed: int
    budget: int
    arm: str | None = None
    ablation: str | None = None
    config: str | None = None
    sets: tuple[str, ...] = ()
    source: str | None = None
    mode: Literal["inline", "service"] = "inline"
    stop_coverage: float | None = None
    max_seconds: float | None = None
    env: str | None = None
    stages: tuple[int, ...] = ()  # an agent-count curriculum (python -m cmcl stages --agents ...); () = one run
    stage_episodes: tuple[int, ...] = ()  # its budget per stage (--stage-episodes); () = `budget` per stage

    def record(self) -> dict[str, Any]:
        """The run's fields as its summary stores them: the seven every summary has, then those set."""
        out: dict[str, Any] = {"id": self.id, "grid": self.grid, "task": self.task, "algorithm": self.algorithm,
                               "prey_algorithm": self.prey_algorithm, "seed": self.seed, "budget": self.budget}
        if self.source is not None:
            out["ablation"] = self.ablation  # a prefix reference: ablation None, its source named
        for key in ("arm", "ablation", "config", "source", "stop_coverage", "max_seconds", "env"):
            if getattr(self, key) is not None:
                out[key] = getattr(self, key)
        if self.sets:
            out["sets"] = list(self.sets)
        if self.stages:
            out["stages"], out["stage_episodes"] = list(self.stages), list(self.stage_episodes)
        if self.mode != "inline":
            out["mode"] = self.mode
        return out

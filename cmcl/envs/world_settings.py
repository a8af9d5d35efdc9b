"""The world settings a task curriculum may change between episodes, per sparse task (`env.factory` path).

Where it sits: `cmcl.rollout.task_curriculum` (the [task_curriculum] section) checks its `param` and `stages` against
`SETTINGS` at config load, and the rollout worker hands each world its stage's value through the env's setter:
`set_world_settings(name, idx int64[M], values float64[M])` on the batched envs (`BatchedSparseNav`,
`cmcl.envs.parallel_vector.VectorParallelEnv`), `set_setting(name, value)` on the ParallelEnvs
(`cmcl.envs.sparse_nav_v0.SparseNavEnv`, `cmcl.envs.cmae_grids.PushBoxEnv` / `PassEnv`). A value set for a world
takes effect at that world's next reset (never inside an episode).

Settings (units; the sources' value is each task's default, the hardest stage):
* navigation (`cmcl.envs.sparse_nav_v0:parallel_env`): `spawn_scale` (the start-distance scale: agents and
  landmarks uniform in spawn_scale x the variant's squares; 1 = the source), `cover_radius` (MPE units: a landmark
  is covered when some agent's centre is closer), `gate` (landmarks: the gated rule pays nothing below it; SPMARL 4).
* Push-Box (`cmcl.envs.cmae_grids:push_box_env`): `push_cells` (cells: the task is solved once the box has moved
  this far from its start along either axis, or touches the border; 6 = the source, centre to border).
* Pass (`cmcl.envs.cmae_grids:pass_env`): `switch_reach` (cells: the door opens while an agent is this close to a
  switch; 4.5 = the source).
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Setting:
    """One settable world parameter: its range [low, high] and whether it takes integers."""

    name: str
    low: float
    high: float
    integer: bool = False
    low_open: bool = False  # the range excludes `low`

    def check(self, value: object, where: str) -> float:
        """`value` as a float within range, else ValueError naming `where` and the value."""
        ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(float(value))
        if ok:
            v = float(value)
            ok = (v > self.low if self.low_open else v >= self.low) and v <= self.high
            ok = ok and (not self.integer or v == round(v))
        if not ok:
            kind = "an integer" if self.integer else "a number"
            bracket = "(" if self.low_open else "["
            raise ValueError(f"{where} = {value!r}: {self.name} must be {kind} in {bracket}{self.low:g}, "
                             f"{self.high:g}]")
        return float(value)  # type: ignore[arg-type]


NAV_FACTORY = "cmcl.envs.sparse_nav_v0:parallel_env"
PUSH_BOX_FACTORY = "cmcl.envs.cmae_grids:push_box_env"
PASS_FACTORY = "cmcl.envs.cmae_grids:pass_env"

SETTINGS: dict[str, dict[str, Setting]] = {
    NAV_FACTORY: {s.name: s for s in (Setting("spawn_scale", 0.0, 10.0, low_open=True),
                                      Setting("cover_radius", 0.0, 10.0, low_open=True),
                                      Setting("gate", 0, 64, integer=True))},
    PUSH_BOX_FACTORY: {"push_cells": Setting("push_cells", 1, 6, integer=True)},
    PASS_FACTORY: {"switch_reach": Setting("switch_reach", 0.0, 42.0, low_open=True)},
}


def setting_of(factory: str, name: str, where: str) -> Setting:
    """The setting `name` of the task `factory` (an env.factory path), else ValueError naming `where`, the name and
    the settings that task has."""
    known = SETTINGS.get(factory)
    if known is None:
        raise ValueError(f"{where} = {name!r}: env.factory {factory!r} has no settable world parameters (tasks that "
                         f"have: {sorted(SETTINGS)})")
    if name not in known:
        raise ValueError(f"{where} = {name!r}: not a setting of {factory!r} (its settings: {sorted(known)})")
    return known[name]

"""Warm start: a new run's actors and critics (and their targets) initialised from another run's newest policy.

Set by `run.init_from = "runs/OTHER"` for a fresh run of either runner; a resumed run takes its own checkpoint
instead. What is carried: the four networks of `MADDPG` (actor, critic, target_actor, target_critic). What starts
afresh: the optimisers' moments, the exploration noise, the update counter, the replay buffer (unless
run.carry_replay: cmcl.run.carried_replay), the teachers, the ICM and every counter of the run. The networks must
have the same shapes, so a run with other agent counts or network settings is refused, naming the tensor and both
shapes; networks whose parameter count does not depend on the number of agents can carry weights from N agents to
another N (the agent-count curriculum), and from one maddpg.entity_nearest to another (the same weights
then read other entities: a deliberate transfer, as between agent counts; a resume or an evaluation of a checkpoint
under another k is refused instead, cmcl.learners.maddpg). A run of another maddpg.entity_holder is
refused, naming that setting (its entity layers take one input more or fewer)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

from cmcl.config import ConfigError
from cmcl.learners.state_check import require_same_holder, require_same_shapes
from cmcl.run.rundir import PolicyCheckpoint, RunDirectory

if TYPE_CHECKING:
    from cmcl.learners.maddpg import MADDPG

WARM_PARTS = ("actor", "critic", "target_actor", "target_critic")  # what a warm start carries over


def warm_start_source(init_from: str) -> PolicyCheckpoint:
    """The newest verified policy of the run directory `init_from`, whichever runner wrote it.
    Raises ConfigError naming run.init_from and its value when there is no run or no policy there."""
    path = Path(init_from)
    if not (path / "config.toml").is_file():
        raise ConfigError(f"run.init_from={init_from!r}: no run directory there (no config.toml)")
    policy = RunDirectory.open(path).newest_policy()
    if policy is None:
        raise ConfigError(f"run.init_from={init_from!r}: the run holds no policy checkpoint that passes its checks")
    return policy


def warm_start_(maddpg: MADDPG, saved: Mapping, source: str) -> None:
    """Copy the networks of a saved `MADDPG.state_dict()` into `maddpg`, in place; nothing else changes.
    Raises ValueError (naming `source`, the tensor and both shapes, or maddpg.entity_holder and both values) before
    any weight is replaced."""
    modules = {name: getattr(maddpg, name) for name in WARM_PARTS}
    require_same_holder(f"run.init_from={source!r}: maddpg", maddpg.entity_holder, saved)
    require_same_shapes(f"run.init_from={source!r}: maddpg", modules, saved,
                        "agent counts, observation sizes or maddpg network settings")
    for name, module in modules.items():
        module.load_state_dict(saved[name])


def warm_start_from_config(init_from: str, maddpg: MADDPG) -> Path | None:
    """Warm-start `maddpg` from `init_from` (run.init_from; "" does nothing). Returns the checkpoint file used."""
    if not init_from:
        return None
    policy = warm_start_source(init_from)
    warm_start_(maddpg, policy.state["maddpg"], init_from)
    return policy.path

"""What an inline run's checkpoint holds, and how an `InlineLoop` is saved to it and restored from it.

Where it sits: `InlineLoop.state_dict / load_state_dict / save_checkpoint / restore` (cmcl/loop/inline.py) are
these functions; the files are the run directory's (`ckpt_<episodes:08d>.pt` and its replay snapshot beside it,
cmcl.io.checkpoint_files). The checkpoint is a dict of torch tensors and plain values: the networks' state dicts,
λ's clock (env steps), the counters, the pacing, run.stop_progress's record, the training wall clock (elapsed_s,
seconds), the worlds' states, their observations float32[B, N, obs_dim] and episode ids int64[B], and the bit
generator state of every generator by name. The replay contents and scores are in the snapshot, not in it.
Checkpoints written before a part was saved still restore: each such part says what it falls back to.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from cmcl.episodes import WorldEpisodes
from cmcl.io.checkpoint_files import (
    load_checkpoint,
    read_replay_snapshot,
    replay_snapshot_path,
    write_replay_snapshot,
)

# `loop` below is a cmcl.loop.inline.InlineLoop (typed Any: this module is below it, it does not import it)
Loop = Any


def loop_state(loop: Loop) -> dict[str, Any]:
    """Everything needed to continue the run except the replay contents (saved as a msgpack snapshot)."""
    return {
        "maddpg": loop.maddpg.state_dict(),
        "teachers": None if loop.teachers is None else loop.teachers.state_dict(),
        "icm": None if loop.icm is None else loop.icm.state_dict(),
        "schedule": {"env_steps": loop.schedule.env_steps},
        "counters": dict(loop.counters),
        "pacing": loop.pacing.state_dict(),
        "learning_progress": loop.learning_progress.state_dict(),
        "elapsed_s": loop.elapsed_s,
        "env": {k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in loop.env.get_state().items()},
        "obs": torch.from_numpy(loop.obs.copy()),
        "episode_ids": torch.from_numpy(loop.episodes.ids.copy()),
        "rng": {name: g.bit_generator.state for name, g in loop.rng.items()},
        "sampler_rng": [g.bit_generator.state for g in loop.sampler_rngs],
    }


def load_loop_state(loop: Loop, state: dict[str, Any]) -> None:
    """Restore a `loop_state()`, world states included, so a resumed run continues exactly."""
    loop.maddpg.load_state_dict(state["maddpg"])
    for name in ("teachers", "icm"):
        model = getattr(loop, name)
        if (model is None) != (state[name] is None):
            raise ValueError(f"checkpoint {name} presence differs from this config's")
        if model is not None:
            model.load_state_dict(state[name])
    loop.schedule.env_steps = int(state["schedule"]["env_steps"])
    # checkpoints before the oldest-score-first rescoring also hold a "rescore_cursor": not used any more
    loop.counters.update({k: int(v) for k, v in state["counters"].items() if k in loop.counters})
    if "pacing" in state:
        loop.pacing.load_state_dict(state["pacing"])
    else:  # checkpoints before the pacing was saved counted its steps in "counters"
        old = state["counters"]
        loop.pacing.restore_counts(old["env_steps"], old["updates"], old.get("teacher_steps", 0),
                                   old.get("icm_steps", 0))
    if "learning_progress" in state:  # checkpoints before run.stop_progress: it starts afresh
        loop.learning_progress.load_state_dict(state["learning_progress"])
    loop.elapsed_s = float(state.get("elapsed_s", 0.0))  # checkpoints before the clock was kept: 0
    for name, g in loop.rng.items():
        g.bit_generator.state = state["rng"][name]
    for g, s in zip(loop.sampler_rngs, state["sampler_rng"], strict=True):
        g.bit_generator.state = s
    fresh_obs = loop.env.set_state({k: v.numpy() for k, v in state["env"].items()})
    b = loop.env.num_envs  # checkpoints before per-world ids: the lock-step ids of round `rounds`
    ids = state["episode_ids"].numpy() if "episode_ids" in state else loop.counters["rounds"] * b + np.arange(b)
    loop.episodes = WorldEpisodes(b, ids)
    loop.obs = state["obs"].numpy().copy()
    if not state["env"]:  # an env.factory world cannot be saved: set_state started new episodes
        loop.obs = fresh_obs
        loop.episodes.advance(np.ones(b, bool))


def save_loop_checkpoint(loop: Loop) -> Path | None:
    """Write the replay snapshot, then the checkpoint, into the loop's run directory (each atomic; None without
    one). The checkpoint is written last, so that a run killed between the two writes never leaves a checkpoint
    without its replay: resume takes the newest checkpoint, which is then always whole."""
    if loop.run_dir is None:
        return None
    path = loop.run_dir.checkpoint_path(loop.counters["episodes"])
    write_replay_snapshot(replay_snapshot_path(path), {"replay": loop.replay.state_dict(),
                                                       **loop.scoring.state_dict()})
    return loop.run_dir.save_checkpoint(loop.counters["episodes"], loop.state_dict())


def restore_loop(loop: Loop, checkpoint: Path) -> None:
    """Load a checkpoint and its replay snapshot, each checked against its digest file and validated before
    anything changes (CheckpointError / codec.CodecError naming the file otherwise)."""
    state = load_checkpoint(checkpoint)
    snapshot = read_replay_snapshot(replay_snapshot_path(checkpoint))
    loop.replay.load_state_dict(snapshot["replay"])
    loop.scoring.load_state_dict(snapshot)
    loop.load_state_dict(state)

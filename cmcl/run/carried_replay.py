"""A new run's start from the replay rows of the run it warm-starts from (`run.carry_replay`), both runners.

Where it sits: a new run with run.init_from and run.carry_replay (the agent-count stages, cmcl.run.agent_stages, set
both for every stage after the first). After the warm start, the replay server (services/roles/replay_server.py, when
it starts without a store of its own) calls `carry_replay_rows`: it reads init_from's newest replay (`_source`: the
replay store snapshot, written at every
checkpoint and at the end of the run), pads its rows to this run's agent count (cmcl.replay.agent_padding: absent
agents zero and masked per row) and adds them to the new buffer, oldest first (its newest `replay.capacity` rows if
they do not all fit). They enter as new rows: their scores unset, PER's priority at the running maximum (the
buffer's default for a new row), policy version 0, their episode ids kept (folds: episode mod K). Learning still
starts after the run's own warm-up (maddpg.warmup transitions of its own environment steps, cmcl.replay.pacing).
`check_carry_source` refuses, before the new run's directory exists, a source with nothing to carry.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cmcl.config import Config, ConfigError
from cmcl.envs.entities import EntityLayout, spread_layout
from cmcl.io.durable import ReplayStore
from cmcl.replay.agent_padding import pad_rows
from cmcl.replay.buffer import ReplayBuffer
from cmcl.replay.snapshot import older_run
from cmcl.replay.storage import TransitionStorage
from cmcl.run.rundir import RunDirectory

__all__ = ["carry_replay_rows", "check_carry_source"]


def _source(init_from: str) -> Path:
    """Where init_from's newest replay rows are: its replay store's folder, whose snapshot both runners write at
    every checkpoint and at the end. ConfigError naming run.carry_replay when there is none."""
    run = RunDirectory.open(init_from) if (Path(init_from) / "config.toml").is_file() else None
    if run is not None and ReplayStore(run.service_replay_dir).manifest_path.is_file():
        return run.service_replay_dir
    if run is not None and "inline" in run.runners():
        raise ConfigError(older_run(f"run.carry_replay=True: run.init_from={init_from!r} holds the inline runner's "
                                    "own checkpoint format"))
    raise ConfigError(f"run.carry_replay=True: run.init_from={init_from!r} holds no replay to carry (no replay "
                      "store)")


def check_carry_source(config: Config) -> None:
    """Refuse run.carry_replay (ConfigError naming the field and the value) without run.init_from, or from a run
    without a replay (`_source`), with more agents than this one or with the other env.agent_tags setting."""
    if not config.run.carry_replay:
        return
    if not config.run.init_from:
        raise ConfigError("run.carry_replay=True needs run.init_from, the run whose replay rows it carries, got ''")
    _source(config.run.init_from)
    source = RunDirectory.open(config.run.init_from).config().env.spread
    if source.agent_tags != config.env.spread.agent_tags:
        raise ConfigError(f"run.carry_replay=True: env.agent_tags={str(config.env.spread.agent_tags).lower()} but "
                          f"run.init_from={config.run.init_from!r} has env.agent_tags="
                          f"{str(source.agent_tags).lower()}; rows are carried between runs with the same setting")
    source_agents = source.num_agents
    if source_agents > config.env.spread.num_agents:
        raise ConfigError(f"run.carry_replay=True: run.init_from={config.run.init_from!r} has {source_agents} "
                          f"agents, more than this run's {config.env.spread.num_agents}; rows are carried to as many "
                          "agents or more")


def source_rows(init_from: str) -> TransitionStorage:
    """The validated storage (TransitionStorage.load_state_dict) of init_from's newest replay (`_source`)."""
    snapshot = ReplayStore(_source(init_from)).read_snapshot()
    state = snapshot["replay"]["storage"]
    storage = TransitionStorage(capacity=state["capacity"], n_agents=state["n_agents"], obs_dim=state["obs_dim"],
                                act_dim=state["act_dim"], n_folds=state["n_folds"])
    storage.load_state_dict(state)
    return storage


def carry_replay_rows(replay: ReplayBuffer, init_from: str, layout: EntityLayout) -> np.ndarray:
    """Add init_from's replay rows, padded to `layout`'s agents, to `replay` (module docstring); returns the slots
    written, int64[T] (−1 for rows a longer source overwrote within the chunk). ValueError naming run.carry_replay
    when the rows do not fit this run's layout."""
    source = source_rows(init_from)
    small = spread_layout(source.n_agents, RunDirectory.open(init_from).config().env.spread.agent_tags)
    if small.obs_dim != source.obs_dim or source.act_dim != replay.storage.act_dim:
        raise ConfigError(f"run.carry_replay=True: the rows of run.init_from={init_from!r} (obs_dim "
                          f"{source.obs_dim}, act_dim {source.act_dim}) are not navigation rows of "
                          f"{source.n_agents} agents with this run's act_dim {replay.storage.act_dim}")
    order = np.argsort(source.id[:source.size], kind="stable")[-replay.capacity:]  # oldest first, newest kept
    rows = source.get(order)
    padded = pad_rows(rows, rows["present"], small, layout)
    return replay.add(padded["obs"], padded["act"], padded["rew"], padded["next_obs"], padded["done"],
                      rows["episode"], policy_version=0, present=padded["present"])

"""The replay buffer's snapshot format: its version, older snapshots read forward, and the control generator's state.

Where it sits: `cmcl.replay.buffer.ReplayBuffer.state_dict` writes format `STATE_FORMAT`; `load_state_dict` passes
whatever it reads through `upgrade_state` first, so a run checkpointed (inline) or snapshotted (replay server) by an
older version resumes.

Formats:
  1 (no "format" key): per-agent "modes" ("uniform" for MADDPG agents), "samplers" {agent: sampler state} for the
    prioritized agents only, and PER's running maxima in one "max_priority" float64[N].
  2: "algorithms" {agent: the config's algorithm}, "sampling" {agent: its sampling distribution's state} for every
    agent (PER's carries its own "max_priority"; MADDPG's is empty).
"""

from __future__ import annotations

from typing import Any

import numpy as np

STATE_FORMAT = 2
_FORMAT_1_NAMES = {"uniform": "maddpg"}  # format 1 named MADDPG's sampling, not the algorithm


def upgrade_state(state: dict[str, Any], n_agents: int) -> dict[str, Any]:
    """A replay `state_dict` of any known format as format `STATE_FORMAT` (a new dict; ValueError for an unknown
    format, naming it)."""
    version = int(state.get("format", 1))
    if version == STATE_FORMAT:
        return state
    if version != 1:
        raise ValueError(f"replay snapshot format {version} is not known to this version (it reads formats 1 to "
                         f"{STATE_FORMAT}); resume it with the version that wrote it")
    modes = {str(k): str(v) for k, v in state["modes"].items()}
    maxp = np.asarray(state["max_priority"], dtype=np.float64)
    if maxp.shape != (n_agents,):
        raise ValueError(f"max_priority must have shape ({n_agents},), got {maxp.shape}")
    sampling = {}
    for agent, mode in modes.items():
        sampling[agent] = dict(state["samplers"].get(agent, {}))
        if mode == "per":
            sampling[agent]["max_priority"] = float(maxp[int(agent)])
    rest = {k: v for k, v in state.items() if k not in ("modes", "samplers", "max_priority")}
    return {**rest, "format": STATE_FORMAT, "sampling": sampling,
            "algorithms": {k: _FORMAT_1_NAMES.get(v, v) for k, v in modes.items()}}


def rng_state(rng: np.random.Generator) -> dict[str, Any]:
    """A PCG64 Generator's state with its 128-bit integers as decimal strings (msgpack holds at most 64 bits)."""
    st = rng.bit_generator.state
    return {"bit_generator": st["bit_generator"], "state": str(st["state"]["state"]), "inc": str(st["state"]["inc"]),
            "has_uint32": int(st["has_uint32"]), "uinteger": int(st["uinteger"])}


def set_rng_state(rng: np.random.Generator, state: dict[str, Any], name: str = "control_rng") -> None:
    """Inverse of `rng_state` (ValueError naming the state's field `name` for another bit generator or malformed
    numbers)."""
    if state.get("bit_generator") != "PCG64":
        raise ValueError(f"{name} must be a PCG64 state, got {state.get('bit_generator')!r}")
    rng.bit_generator.state = {"bit_generator": "PCG64",
                               "state": {"state": int(state["state"]), "inc": int(state["inc"])},
                               "has_uint32": int(state["has_uint32"]), "uinteger": int(state["uinteger"])}

"""The replay buffer's snapshot format: its version, the refusal of older ones, and the control generator's state.

Where it sits: `cmcl.replay.buffer.ReplayBuffer.state_dict` writes format `STATE_FORMAT`; `load_state_dict` reads
that format only (`require_format`): "algorithms" {agent: the config's algorithm}, "sampling" {agent: its sampling
distribution's state} for every agent. The replay server's snapshot and a run directory's config.toml are refused the
same way when they lack what this version writes (`older_run`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

STATE_FORMAT = 2
# the last commit that reads the project's older layouts (replay snapshot format 1 and the fields added since,
# config keys that moved into [teams.<team>.priority] or were removed): an older run is refused naming it
LAST_READER = "4e14724"


class OlderRunError(ValueError):
    """A run directory, snapshot or log written by an older version, refused (`older_run`'s line)."""


def older_run(what: str) -> str:
    """The one line refusing a run written by an older version: `what` names the field or format."""
    return f"{what}: written by an older version; commit {LAST_READER} is the last that reads it"


def require_format(state: dict[str, Any], *fields: str) -> None:
    """OlderRunError (`older_run`) unless `state` is of format `STATE_FORMAT` and holds every one of `fields`."""
    version = state.get("format", 1)
    if version != STATE_FORMAT:
        raise OlderRunError(older_run(f"replay snapshot format {version!r} (this version reads {STATE_FORMAT})"))
    missing = [name for name in fields if name not in state]
    if missing:
        raise OlderRunError(older_run(f"replay snapshot without {missing[0]!r}"))


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

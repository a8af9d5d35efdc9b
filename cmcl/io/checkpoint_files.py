"""The inline runner's checkpoint files: `ckpt_<episodes:08d>.pt` (torch.save of plain state dicts) and, beside each,
`replay_<episodes:08d>.msgpack` (the replay snapshot, cmcl.io.codec), each with its digest file `<file>.sha256`.

Where it sits: the run directory (cmcl.run.rundir) saves and checks its checkpoints with these; the replay
server writes and reads its snapshots, `cmcl.run.carried_replay` reads the one a new run
carries its rows from, `cmcl.run.evaluate` loads the checkpoint named by --checkpoint.
Every write is all or nothing, the file then its digest file (`cmcl.io.verified.write_checked`); every read checks
the digest file before the bytes reach a decoder (`read_checked`), and torch only decodes with weights_only=True.
torch and the codec are imported on first use: a command that only takes the run directory's lock loads neither.
"""

from __future__ import annotations

import io
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from cmcl.io.verified import CheckpointError, read_checked, write_checked


def save_torch_atomic(path: str | Path, state: Mapping[str, Any]) -> None:
    """torch.save `state` (tensors and plain containers, no numpy) to `path`, all or nothing, then its digest file
    `<path>.sha256` ("<hex digest> <bytes>"), which `load_checkpoint` checks before decoding."""
    import torch

    buffer = io.BytesIO()
    torch.save(dict(state), buffer)
    write_checked(path, buffer.getvalue())


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    """Load a checkpoint written by `save_torch_atomic`: checked against its digest file first (a missing,
    truncated or corrupted file, or one without a digest file, raises `CheckpointError` naming it), then
    torch.load(weights_only=True): no arbitrary pickle. A file that cannot be verified is never decoded."""
    import torch

    return torch.load(io.BytesIO(read_checked(path)), map_location="cpu", weights_only=True)


def replay_snapshot_path(checkpoint: Path) -> Path:
    """The replay snapshot an inline run writes beside a checkpoint file (ckpt_N.pt -> replay_N.msgpack)."""
    return checkpoint.with_name(checkpoint.name.replace("ckpt_", "replay_").replace(".pt", ".msgpack"))


def write_replay_snapshot(path: str | Path, state: dict[str, Any]) -> int:
    """Encode a replay snapshot (msgpack, `cmcl.io.codec`) and write it with its digest file, like a checkpoint;
    returns its bytes."""
    from cmcl.io import codec

    payload = codec.encode_snapshot(state)
    write_checked(path, payload)
    return len(payload)


def read_replay_snapshot(path: str | Path) -> dict[str, Any]:
    """A replay snapshot written by `write_replay_snapshot`: checked against its digest file (CheckpointError naming
    the file when it is missing, truncated, flipped or has no digest file), then decoded within the snapshot
    limits (codec.CodecError)."""
    from cmcl.io import codec

    path = Path(path)
    size = path.stat().st_size if path.exists() else 0
    if size > codec.SNAPSHOT_LIMITS.max_bytes:
        raise CheckpointError(f"{path}: {size} bytes exceeds the limit of {codec.SNAPSHOT_LIMITS.max_bytes}")
    return codec.decode_snapshot(read_checked(path), limits=codec.SNAPSHOT_LIMITS)

"""A torch checkpoint file with its digest file `<file>.sha256`: `save_torch_atomic` writes one, `load_checkpoint`
reads one back.

Where it sits: `cmcl.run.evaluate` loads the checkpoint named by --checkpoint with `load_checkpoint`.
Every write is all or nothing, the file then its digest file (`cmcl.io.verified.write_checked`); every read checks
the digest file before the bytes reach a decoder (`read_checked`), and torch only decodes with weights_only=True.
torch is imported on first use: a command that only takes the run directory's lock does not load it.
"""

from __future__ import annotations

import io
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from cmcl.io.verified import read_checked, write_checked


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

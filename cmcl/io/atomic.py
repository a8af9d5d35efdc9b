"""All-or-nothing file writes: temp file in the same directory, fsync, os.replace, fsync of the directory.

Where it sits: every file the project writes for recovery (checkpoints, replay snapshots, configs, the
supervisor's counters) goes through `atomic_write_bytes`, so a crash leaves the old file or the new one; a write the
device refuses (a full disk) raises `cmcl.io.write_failure.RunWriteError` naming the file, the old file kept.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from cmcl.io.write_failure import write_error


def atomic_write_bytes(path: str | os.PathLike, payload: bytes) -> int:
    """Write `payload` to `path` atomically (creating the parent folder); returns the bytes written."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as err:
        raise write_error(err, path) from None
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(payload)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException as err:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(err, OSError):
            raise write_error(err, path) from None
        raise
    dir_fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)
    return len(payload)

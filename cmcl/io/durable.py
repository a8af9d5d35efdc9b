"""Durable replay state: an atomic snapshot checked against a manifest, plus an append-only log of the chunks
accepted since that snapshot.

Where it sits: `services.replay_server.ReplayServer` owns one `ReplayStore`. Every accepted chunk is appended to
the log (one frame: magic, payload length, SHA-256 of the payload, the payload = `cmcl.io.records` bytes) and
flushed before the insert is acknowledged; `snapshot` writes the whole server state atomically under a new
generation, then the manifest (atomically) that names the snapshot, its SHA-256 and the new, empty log; only then
are the old files removed. A restarted server `load`s the manifest, checks the snapshot's hash, and replays the
log. A torn log tail (a frame cut by a crash) or a corrupt frame ends the replay there: the log is truncated to
its last good frame and the problem reported, never fatal. A missing or corrupt snapshot or manifest raises
`StoreError` naming the file.

Layout of the store directory: manifest.json, snapshot-<gen>.msgpack, log-<gen>.bin.
"""

from __future__ import annotations

import hashlib
import json
import os
import struct
from pathlib import Path
from typing import Any

from cmcl.io import codec
from cmcl.io.atomic import atomic_write_bytes

MAGIC = b"CMCL"
FRAME = struct.Struct("<4sQ32s")  # magic, payload bytes, sha256(payload)
MAX_FRAME_BYTES = 1 << 30


class StoreError(ValueError):
    """A snapshot or manifest is missing, truncated or does not match its recorded hash."""


def frame(payload: bytes) -> bytes:
    """One log frame: header (magic, length, SHA-256) + payload."""
    return FRAME.pack(MAGIC, len(payload), hashlib.sha256(payload).digest()) + payload


def read_frames(data: bytes) -> tuple[list[bytes], int, str | None]:
    """The good frames at the start of a log's bytes: (payloads, bytes they span, why reading stopped or None)."""
    frames, pos = [], 0
    while pos < len(data):
        if len(data) - pos < FRAME.size:
            return frames, pos, f"torn frame header at byte {pos}"
        magic, length, digest = FRAME.unpack_from(data, pos)
        if magic != MAGIC or length > MAX_FRAME_BYTES:
            return frames, pos, f"bad frame header at byte {pos}"
        payload = data[pos + FRAME.size:pos + FRAME.size + length]
        if len(payload) < length:
            return frames, pos, f"torn frame at byte {pos} ({len(payload)} of {length} payload bytes)"
        if hashlib.sha256(payload).digest() != digest:
            return frames, pos, f"checksum mismatch in the frame at byte {pos}"
        frames.append(payload)
        pos += FRAME.size + length
    return frames, pos, None


class ReplayStore:
    """Snapshot + manifest + log in `root`. `fsync`: also fsync every log append (survives power loss, slower)."""

    def __init__(self, root: str | os.PathLike, fsync: bool = False):
        self.root, self.fsync = Path(root), bool(fsync)
        self.generation = 0
        self._log = None

    @property
    def manifest_path(self) -> Path:
        return self.root / "manifest.json"

    def _log_path(self, generation: int) -> Path:
        return self.root / f"log-{generation:06d}.bin"

    def exists(self) -> bool:
        """Whether this store holds anything to restore (a manifest, or a log written before the first snapshot)."""
        return self.manifest_path.exists() or self._log_path(0).exists()

    def load(self) -> tuple[dict[str, Any] | None, list[bytes], str | None]:
        """(the snapshot state or None before the first snapshot, the logged chunk payloads since it, the log
        problem or None); the log is then open for appending, truncated to its good frames. StoreError if the
        manifest or the snapshot is bad."""
        if not self.manifest_path.exists():
            return None, *self._replay_log(0)
        state, generation = self._read_snapshot()
        return state, *self._replay_log(generation)

    def read_snapshot(self) -> dict[str, Any] | None:
        """The snapshot state (checked against the manifest), None before the first snapshot; read only: the log is
        neither read nor opened (another run reading a finished run's replay, run.carry_replay)."""
        return self._read_snapshot()[0] if self.manifest_path.exists() else None

    def _read_snapshot(self) -> tuple[dict[str, Any], int]:
        """(the state of the snapshot the manifest names, its generation); StoreError naming a bad file."""
        try:
            manifest = json.loads(self.manifest_path.read_text())
            generation, name, digest = int(manifest["generation"]), str(manifest["snapshot"]), manifest["sha256"]
        except (OSError, ValueError, KeyError, TypeError) as err:
            raise StoreError(f"replay manifest {self.manifest_path}: unreadable ({err})") from err
        path = self.root / name
        try:
            data = path.read_bytes()
        except OSError as err:
            raise StoreError(f"replay snapshot {path}: missing ({err})") from err
        if hashlib.sha256(data).hexdigest() != digest:
            raise StoreError(f"replay snapshot {path}: SHA-256 does not match the manifest (truncated or corrupt)")
        try:
            state = codec.decode_snapshot(data, limits=codec.SNAPSHOT_LIMITS)
        except codec.CodecError as err:
            raise StoreError(f"replay snapshot {path}: {err}") from err
        return state, generation

    def _replay_log(self, generation: int) -> tuple[list[bytes], str | None]:
        """The good frames of generation's log (truncated to them), which is then open for appending."""
        log = self._log_path(generation)
        frames, good, problem = read_frames(log.read_bytes() if log.exists() else b"")
        if problem is not None:
            os.truncate(log, good)
        self.generation = generation
        self._open_log()
        return frames, problem

    def _open_log(self) -> None:
        if self._log is not None:
            self._log.close()
        self.root.mkdir(parents=True, exist_ok=True)
        self._log = open(self._log_path(self.generation), "ab")  # noqa: SIM115 - held open for appends

    def append(self, payload: bytes) -> None:
        """Append one chunk frame and flush it to the OS (and to disk with fsync) before returning."""
        if self._log is None:
            self._open_log()
        self._log.write(frame(payload))
        self._log.flush()
        if self.fsync:
            os.fsync(self._log.fileno())

    def snapshot(self, state: dict[str, Any]) -> int:
        """Write `state` as a new generation, switch the manifest to it with an empty log, drop the old files.
        Returns the snapshot's bytes."""
        self.root.mkdir(parents=True, exist_ok=True)
        old, new = self.generation, self.generation + 1
        data = codec.encode_snapshot(state)
        name = f"snapshot-{new:06d}.msgpack"
        atomic_write_bytes(self.root / name, data)
        self._log_path(new).touch()
        manifest = {"generation": new, "snapshot": name, "sha256": hashlib.sha256(data).hexdigest(),
                    "log": self._log_path(new).name}
        atomic_write_bytes(self.manifest_path, json.dumps(manifest).encode())  # the switch: atomic rename
        self.generation = new
        self._open_log()
        for stale in (self.root / f"snapshot-{old:06d}.msgpack", self._log_path(old)):
            stale.unlink(missing_ok=True)
        return len(data)

    def close(self) -> None:
        if self._log is not None:
            self._log.close()
            self._log = None

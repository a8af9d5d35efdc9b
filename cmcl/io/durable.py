"""Durable replay state: an atomic snapshot checked against a manifest, plus an append-only log of the chunks
accepted since that snapshot.

Where it sits: `services.roles.replay_server.ReplayServer` owns one `ReplayStore`. Every accepted chunk is appended to
the log (one frame: a header of magic, payload length, transitions, SHA-256 of the payload and a CRC-32 of the
header; then the payload = `cmcl.io.records` bytes) and flushed before the insert is acknowledged; `snapshot`
writes the whole server state atomically under a new generation, then the manifest (atomically) that names the
snapshot, its SHA-256 and the new, empty log; only then are the old files removed. A restarted server `load`s the
manifest, checks the snapshot's hash, and replays the log. Frames are independent (each chunk is keyed by writer,
incarnation and seq): a corrupt frame is skipped and counted (its transitions too, from its header), every frame
after it that verifies is kept, and a torn tail (a frame cut by a crash, never acknowledged) is dropped. A damaged
log is moved aside whole (`log-<gen>.bin.damaged-<k>`), never cut, and a new log holding exactly its good frames
takes its place; `LogDamage` says what was lost and where the copy is. A missing or corrupt snapshot or manifest
raises `StoreError` naming the file.

Layout of the store directory: manifest.json, snapshot-<gen>.msgpack, log-<gen>.bin (+ any damaged copies).
"""

from __future__ import annotations

import hashlib
import json
import os
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cmcl.io import codec
from cmcl.io.atomic import atomic_write_bytes
from cmcl.io.write_failure import write_error
from cmcl.replay.snapshot import older_run

MAGIC = b"CML2"
FRAME = struct.Struct("<4sQI32sI")  # magic, payload bytes, transitions, sha256(payload), crc32(the 48 bytes before)
LEGACY_MAGIC = b"CMCL"  # the frames of an older version (no transitions, no header CRC): refused
MAX_FRAME_BYTES = 1 << 30


class StoreError(ValueError):
    """A snapshot or manifest is missing, truncated or does not match its recorded hash."""


def frame(payload: bytes, transitions: int = 0) -> bytes:
    """One log frame: header (magic, length, transitions, SHA-256, header CRC-32) + payload. `transitions`: the
    rows of the chunk it holds (0 for an event)."""
    head = FRAME.pack(MAGIC, len(payload), int(transitions), hashlib.sha256(payload).digest(), 0)[:-4]
    return head + struct.pack("<I", zlib.crc32(head)) + payload


def _header(data: bytes, pos: int) -> tuple[int, int, int, bytes] | None:
    """The frame header at `pos` if one is there: (header bytes, payload bytes, transitions, payload SHA-256); None
    when the bytes at `pos` are not a whole, intact header."""
    magic = data[pos:pos + 4]
    if magic == MAGIC and len(data) - pos >= FRAME.size:
        _, length, rows, digest, crc = FRAME.unpack_from(data, pos)
        if zlib.crc32(data[pos:pos + FRAME.size - 4]) == crc and length <= MAX_FRAME_BYTES:
            return FRAME.size, length, rows, digest
    return None


def _next_header(data: bytes, start: int) -> int:
    """The first position >= `start` holding an intact frame header, or len(data)."""
    while start < len(data):
        hit = data.find(MAGIC, start)
        if hit < 0:
            return len(data)
        if _header(data, hit) is not None:
            return hit
        start = hit + 1
    return len(data)


@dataclass
class LogScan:
    """What `read_frames` found in a log's bytes. Byte ranges are [start, end) offsets into the log."""

    frames: list[bytes] = field(default_factory=list)  # the payloads of the frames that verify, in log order
    spans: list[tuple[int, int]] = field(default_factory=list)  # where each of those frames lies
    damaged: list[tuple[int, int]] = field(default_factory=list)  # skipped ranges (torn tail included)
    lost_frames: int = 0  # whole frames whose payload failed its SHA-256 (their header intact)
    lost_transitions: int = 0  # the transitions those frames held, from their headers
    unknown_ranges: int = 0  # damaged ranges with no intact header: how many frames and transitions is unknown
    torn_tail: int | None = None  # offset of a frame cut at the end of the log (a crash mid-append), else None

    @property
    def problem(self) -> str | None:
        """One line: what was lost and where; None for a log whose every byte verifies."""
        if not self.damaged:
            return None
        parts = []
        if self.lost_frames:
            parts.append(f"{self.lost_frames} corrupt frame(s) skipped ({self.lost_transitions} transitions lost)")
        if self.unknown_ranges:
            parts.append(f"{self.unknown_ranges} damaged range(s) without a readable header (transitions unknown)")
        if self.torn_tail is not None:
            parts.append(f"a torn last frame at byte {self.torn_tail} dropped (cut by a crash, never acknowledged)")
        where = ", ".join(f"{a}-{b}" for a, b in self.damaged[:5]) + (" ..." if len(self.damaged) > 5 else "")
        return f"{'; '.join(parts)}; damaged bytes {where}; {len(self.frames)} good frames kept"

    def _skip(self, start: int, end: int) -> None:
        if self.damaged and self.damaged[-1][1] == start:
            self.damaged[-1] = (self.damaged[-1][0], end)
        else:
            self.damaged.append((start, end))


def read_frames(data: bytes) -> LogScan:
    """Every frame of a log's bytes that verifies, with what was skipped. A frame whose header is intact (CRC)
    but whose payload fails its SHA-256 is skipped by its recorded length; bytes without an intact header are
    skipped up to the next intact header; a frame cut by the end of the data is a torn tail. StoreError for a log
    of an older version's frames (`LEGACY_MAGIC`)."""
    if data.startswith(LEGACY_MAGIC):
        raise StoreError(older_run(f"replay log of frame format {LEGACY_MAGIC.decode()!r}"))
    out, pos = LogScan(), 0
    while pos < len(data):
        head = _header(data, pos)
        if head is None:
            nxt = _next_header(data, pos)
            if nxt == len(data) and len(data) - pos < FRAME.size and MAGIC.startswith(data[pos:pos + 4]):
                out.torn_tail = pos  # a header cut by the end of the log
            else:
                out.unknown_ranges += 1
            out._skip(pos, nxt)
            pos = nxt
            continue
        size, length, rows, digest = head
        end = pos + size + length
        if end > len(data):
            out.torn_tail = pos
            out._skip(pos, len(data))
            break
        payload = data[pos + size:end]
        if hashlib.sha256(payload).digest() == digest:
            out.frames.append(payload)
            out.spans.append((pos, end))
            pos = end
        else:
            out.lost_frames += 1
            out.lost_transitions += rows
            out._skip(pos, end)
            pos = end
    return out


@dataclass(frozen=True)
class LogDamage:
    """A damaged replay log found at load: what `read_frames` found, and where the damaged file now lies."""

    scan: LogScan
    copy: Path  # the damaged log, moved aside whole

    def __str__(self) -> str:
        return f"{self.scan.problem}; the damaged log is kept at {self.copy}"


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

    def load(self) -> tuple[dict[str, Any] | None, list[bytes], LogDamage | None]:
        """(the snapshot state or None before the first snapshot, the logged payloads since it that verify, the
        log's damage or None); the log is then open for appending (a damaged one moved aside first, see
        `_replay_log`). StoreError if the manifest or the snapshot is bad."""
        if not self.manifest_path.exists():
            return None, *self._replay_log(0)
        state, generation = self._read_snapshot()
        return state, *self._replay_log(generation)

    def recover_log(self) -> LogDamage | None:
        """Check the current log as `load` does (a damaged one moved aside and replaced by its good frames) without
        decoding the snapshot, then close it: what a resume tells the user before the replay server starts. None
        for an intact log, or when the manifest is unreadable (`load` then refuses it, naming the file)."""
        try:
            generation = int(json.loads(self.manifest_path.read_text())["generation"]) if self.manifest_path.exists() \
                else 0
        except (OSError, ValueError, KeyError, TypeError):
            return None
        damage = self._replay_log(generation)[1]
        self.close()
        return damage

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

    def _replay_log(self, generation: int) -> tuple[list[bytes], LogDamage | None]:
        """The good frames of generation's log, which is then open for appending. A damaged log is moved aside
        whole and replaced (atomically) by one holding exactly its good frames, byte for byte."""
        log = self._log_path(generation)
        data = log.read_bytes() if log.exists() else b""
        scan = read_frames(data)
        damage = None
        if scan.damaged:
            copy = next(c for k in range(1, 1 << 20)
                        if not (c := log.with_name(f"{log.name}.damaged-{k}")).exists())
            os.replace(log, copy)
            atomic_write_bytes(log, b"".join(data[a:b] for a, b in scan.spans))
            damage = LogDamage(scan, copy)
        self.generation = generation
        self._open_log()
        return scan.frames, damage

    def _open_log(self) -> None:
        if self._log is not None:
            self._log.close()
        self.root.mkdir(parents=True, exist_ok=True)
        self._log = open(self._log_path(self.generation), "ab")  # noqa: SIM115 - held open for appends

    def append(self, payload: bytes, transitions: int = 0) -> None:
        """Append one frame (a chunk of `transitions` rows, or an event: 0) and flush it to the OS (and to disk with
        fsync) before returning."""
        try:
            if self._log is None:
                self._open_log()
            self._log.write(frame(payload, transitions))
            self._log.flush()
            if self.fsync:
                os.fsync(self._log.fileno())
        except OSError as err:  # a full disk: the frame may be torn, and is set aside on resume (`_replay_log`)
            raise write_error(err, self._log_path(self.generation)) from None

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

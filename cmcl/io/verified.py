"""Checkpoint files checked against a manifest before anything reads them, with the previous one kept.

Where it sits: the learner, teacher and ICM actors of services/ save their state through `VerifiedFile`
(via services.common). Each save writes a new generation `<stem>-<gen>.<suffix>` (atomic), then switches the
manifest `<name>.manifest.json` (atomic: temp file + rename) to it, naming its size and SHA-256 and the previous
generation's, then deletes older generations. A reader checks the manifest, then the file's size and digest
against it, before the bytes reach a decoder: a missing, truncated or bit-flipped file is refused with its name
and reason, and the previous generation is tried next. A crash at any point leaves the manifest naming complete
files only.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cmcl.io.atomic import atomic_write_bytes

MANIFEST_LIMIT = 64 * 1024  # bytes; a manifest is a few hundred


class CheckpointError(ValueError):
    """A checkpoint file or its manifest failed a check; the message names the file and the check."""


@dataclass
class Loaded:
    """What `VerifiedFile.load` found: the payload (None: no usable checkpoint) and every refusal on the way."""

    payload: bytes | None = None
    generation: int | None = None
    refused: list[str] = field(default_factory=list)  # "file: reason", newest first


class VerifiedFile:
    """The checkpoint of one role at `path` (e.g. .../learner.pt), kept as manifest + two generations."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.manifest = self.path.with_name(self.path.name + ".manifest.json")

    def file_of(self, generation: int) -> Path:
        """The file of one generation: `<stem>-<generation:06d><suffix>`."""
        return self.path.with_name(f"{self.path.stem}-{generation:06d}{self.path.suffix}")

    def _read_manifest(self) -> dict[str, Any] | None:
        """The manifest's entries, None when there is none; CheckpointError when it is unreadable."""
        if not self.manifest.exists():
            return None
        raw = self.manifest.read_bytes()
        if len(raw) > MANIFEST_LIMIT:
            raise CheckpointError(f"{self.manifest}: {len(raw)} bytes, over the {MANIFEST_LIMIT}-byte cap")
        try:
            data = json.loads(raw)
            entries = [data["current"], *([data["previous"]] if data.get("previous") else [])]
            for e in entries:
                int(e["generation"]), int(e["bytes"]), str(e["sha256"])
        except (ValueError, KeyError, TypeError) as err:
            raise CheckpointError(f"{self.manifest}: not a checkpoint manifest ({err})") from err
        return data

    def save(self, payload: bytes) -> Path:
        """Write `payload` as the next generation, switch the manifest to it, delete the generations before the
        previous one; returns the new file."""
        try:
            previous = (self._read_manifest() or {}).get("current")
        except CheckpointError:
            previous = None  # an unreadable manifest names nothing worth keeping
        generation = 1 + (int(previous["generation"]) if previous else 0)
        target = self.file_of(generation)
        atomic_write_bytes(target, payload)
        entry = {"generation": generation, "file": target.name, "bytes": len(payload),
                 "sha256": hashlib.sha256(payload).hexdigest()}
        atomic_write_bytes(self.manifest, json.dumps({"current": entry, "previous": previous}).encode())
        keep = {target.name, previous["file"] if previous else None}
        for old in self.path.parent.glob(f"{self.path.stem}-*{self.path.suffix}"):
            if old.name not in keep:
                old.unlink(missing_ok=True)
        return target

    def load(self) -> Loaded:
        """The newest generation that passes its checks (size, SHA-256); refusals are listed, never raised."""
        out = Loaded()
        try:
            data = self._read_manifest()
        except CheckpointError as err:
            out.refused.append(str(err))
            return out
        if data is None:
            return out
        for entry in (data["current"], data.get("previous")):
            if not entry:
                continue
            file = self.file_of(int(entry["generation"]))
            try:
                out.payload, out.generation = check(file, int(entry["bytes"]), str(entry["sha256"])), \
                    int(entry["generation"])
                return out
            except CheckpointError as err:
                out.refused.append(str(err))
        return out


def check(file: Path, size: int, sha256: str) -> bytes:
    """The bytes of `file` if they have the manifest's size and SHA-256; CheckpointError naming the failure."""
    if not file.exists():
        raise CheckpointError(f"{file}: missing (named by its manifest)")
    if file.stat().st_size != size:
        raise CheckpointError(f"{file}: {file.stat().st_size} bytes, the manifest says {size} (truncated?)")
    payload = file.read_bytes()
    if hashlib.sha256(payload).hexdigest() != sha256:
        raise CheckpointError(f"{file}: SHA-256 differs from its manifest (corrupted)")
    return payload

"""Checkpoint files checked before anything reads them, with the previous generation kept.

Where it sits: the learner, teacher and ICM actors of services/ save their state through `VerifiedFile`
(via services.runtime.common); the inline runner's checkpoints and replay snapshots use `write_checked` / `read_checked`
(via cmcl.io.checkpoint_files). Each `VerifiedFile` save writes a new generation `<stem>-<gen>.<suffix>` and its digest
file `<file>.sha256` (SHA-256 and size; each atomic), reads it back and checks it, then switches the manifest
`<name>.manifest.json` (atomic: temp file + rename) to it, naming its size and SHA-256 and the previous verified
generation's, and only then deletes older generations. A reader checks every generation on disk, newest first,
against its manifest entry or else its own digest file, before the bytes reach a decoder: a missing, truncated or
bit-flipped file is refused with its name and reason, and the one before it is tried. A lost or unreadable
manifest is rebuilt from the digest files; it never makes a generation look absent. New generations are numbered
above every generation on disk.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cmcl.io.atomic import atomic_write_bytes

MANIFEST_LIMIT = 64 * 1024  # bytes; a manifest is a few hundred
DIGEST_LIMIT = 1024  # bytes; a digest file is "<64 hex> <size>"


class CheckpointError(ValueError):
    """A checkpoint file or its manifest failed a check; the message names the file and the check."""


class Unverifiable(CheckpointError):
    """A file with no checksum anywhere (no manifest entry, no digest file): it may be intact, so it is never
    trusted and never deleted in favour of a fresh start."""


@dataclass
class Loaded:
    """What `VerifiedFile.load` found: the payload (None: no usable checkpoint) and every refusal on the way."""

    payload: bytes | None = None
    generation: int | None = None
    refused: list[str] = field(default_factory=list)  # "file: reason", newest first
    unverifiable: list[Path] = field(default_factory=list)  # generation files that carry no checksum at all


def digest_path(path: str | Path) -> Path:
    """The digest file of `path`: `<path>.sha256`, holding "<SHA-256 hex> <bytes>"."""
    return Path(str(path) + ".sha256")


def write_checked(path: str | Path, payload: bytes) -> Path:
    """Write `payload` to `path`, then its digest file (`digest_path`), each atomically; returns `path`. A crash
    between the two leaves a file without a digest, which `read_checked` refuses."""
    path = Path(path)
    atomic_write_bytes(path, payload)
    atomic_write_bytes(digest_path(path), f"{hashlib.sha256(payload).hexdigest()} {len(payload)}".encode())
    return path


def read_checked(path: str | Path) -> bytes:
    """The bytes of `path` if they match its digest file; `Unverifiable` when there is no digest file, else
    CheckpointError naming the file and the failed check."""
    path = Path(path)
    digest = digest_path(path)
    if not digest.exists():
        raise Unverifiable(f"{path}: no {digest.name} beside it, so it cannot be verified")
    try:
        raw = digest.read_bytes()[:DIGEST_LIMIT].decode()
        sha256, size = raw.split()
        return check(path, int(size), sha256)
    except (ValueError, UnicodeDecodeError) as err:
        if isinstance(err, CheckpointError):
            raise
        raise CheckpointError(f"{digest}: not a checkpoint digest ({err})") from err


class VerifiedFile:
    """The checkpoint of one role at `path` (e.g. .../learner.pt): generation files, each with its digest file,
    and a manifest naming the current and the previous generation."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.manifest = self.path.with_name(self.path.name + ".manifest.json")
        self._pattern = re.compile(rf"{re.escape(self.path.stem)}-(\d{{6,}}){re.escape(self.path.suffix)}")

    def file_of(self, generation: int) -> Path:
        """The file of one generation: `<stem>-<generation:06d><suffix>`."""
        return self.path.with_name(f"{self.path.stem}-{generation:06d}{self.path.suffix}")

    def generations(self) -> list[int]:
        """The generations whose files are on disk (whatever their state), newest first."""
        names = (p.name for p in self.path.parent.glob(f"{self.path.stem}-*{self.path.suffix}"))
        return sorted((int(m.group(1)) for m in map(self._pattern.fullmatch, names) if m), reverse=True)

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

    def _newest(self, below: int | None = None) -> Loaded:
        """The newest generation (< `below` if given) that verifies against its manifest entry, or else its own
        digest file; every generation on disk or in the manifest is tried, newest first. An unreadable manifest is
        a refusal like any other, never a reason to pass over the files."""
        out, named = Loaded(), {}
        try:
            data = self._read_manifest() or {}
            named = {int(e["generation"]): e for e in (data.get("current"), data.get("previous")) if e}
        except CheckpointError as err:
            out.refused.append(str(err))
        for generation in sorted({*self.generations(), *named}, reverse=True):
            if below is not None and generation >= below:
                continue
            file, entry = self.file_of(generation), named.get(generation)
            try:
                out.payload = (check(file, int(entry["bytes"]), str(entry["sha256"])) if entry
                               else read_checked(file))
                out.generation = generation
                return out
            except Unverifiable as err:
                out.refused.append(str(err))
                out.unverifiable.append(file)
            except CheckpointError as err:
                out.refused.append(str(err))
        return out

    def save(self, payload: bytes) -> Path:
        """Write `payload` as the next generation (numbered above every generation on disk or in the manifest) with
        its digest file, check it back, switch the manifest to it, then delete the generations older than it
        except the newest one before it that verifies; returns the new file. CheckpointError (nothing deleted)
        when the new file does not read back intact."""
        try:
            named = [int(e["generation"]) for e in ((self._read_manifest() or {}).get("current"),) if e]
        except CheckpointError:
            named = []
        generation = 1 + max([*self.generations(), *named], default=0)
        target = write_checked(self.file_of(generation), payload)
        read_checked(target)  # the new generation verifies before any older one goes
        previous = self._newest(below=generation)
        entry = {"generation": generation, "file": target.name, "bytes": len(payload),
                 "sha256": hashlib.sha256(payload).hexdigest()}
        before = None if previous.payload is None else {
            "generation": previous.generation, "file": self.file_of(previous.generation).name,
            "bytes": len(previous.payload), "sha256": hashlib.sha256(previous.payload).hexdigest()}
        atomic_write_bytes(self.manifest, json.dumps({"current": entry, "previous": before}).encode())
        for old in self.generations():
            if old not in (generation, previous.generation):
                self.file_of(old).unlink(missing_ok=True)
                digest_path(self.file_of(old)).unlink(missing_ok=True)
        return target

    def load(self) -> Loaded:
        """The newest generation that passes its checks (size, SHA-256); refusals are listed, never raised."""
        return self._newest()


def check(file: Path, size: int, sha256: str) -> bytes:
    """The bytes of `file` if they have the recorded size and SHA-256; CheckpointError naming the failure."""
    if not file.exists():
        raise CheckpointError(f"{file}: missing (named by its manifest)")
    if file.stat().st_size != size:
        raise CheckpointError(f"{file}: {file.stat().st_size} bytes, the checksum says {size} (truncated?)")
    payload = file.read_bytes()
    if hashlib.sha256(payload).hexdigest() != sha256:
        raise CheckpointError(f"{file}: SHA-256 differs from its checksum (corrupted)")
    return payload

"""A run's metrics file, `<run dir>/metrics.jsonl`: one JSON object per line (episode rows and update rows, each with
a "kind"), appended one row at a time and read back in order.

Where it sits: the run directory (cmcl.run.rundir) keeps one `MetricsLog` and answers `log` / `rows` with it; both
runners append through it, `cmcl.run.evaluate`, the plots and experiments/ read through it. It touches only the metrics
file and, beside it, `metrics.jsonl.torn` (a last line cut by a crash or a full disk, set aside before the next
append). Numpy / torch values are written as JSON values (`json_safe`), non-finite floats as null.
"""

from __future__ import annotations

import json
import math
import os
import sys
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from cmcl.io.atomic import atomic_write_bytes
from cmcl.io.write_failure import write_error

TAIL_BYTES = 1 << 20  # the last line of metrics.jsonl is looked for in its last MiB


class MetricsError(ValueError):
    """metrics.jsonl holds a line that does not parse and is not its last: the message names the file and line."""


def _parse_row(line: bytes) -> dict[str, Any] | None:
    """One metrics line as its row, or None when it is not a JSON object."""
    try:
        row = json.loads(line)
    except (ValueError, UnicodeDecodeError):
        return None
    return row if isinstance(row, dict) else None


def json_safe(value: Any) -> Any:
    """Convert numpy / torch scalars and arrays to JSON values; non-finite floats become None."""
    if isinstance(value, Mapping):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    if hasattr(value, "tolist"):
        return json_safe(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


class MetricsLog:
    """The metrics rows of one run, in the file `path` (which need not exist yet)."""

    def __init__(self, path: Path):
        self.path = path
        self._tail_checked = self._torn_said = False  # torn last line set aside (`append`) / said (`rows`)

    def append(self, row: Mapping[str, Any]) -> None:
        """Append one metrics row (a flat or nested mapping) as a JSON line (the first append of this object first
        moves a torn last line aside, `_set_torn_line_aside`, so that no row is ever glued to it)."""
        if not self._tail_checked:
            self._set_torn_line_aside()
            self._tail_checked = True
        try:
            with self.path.open("a") as handle:
                handle.write(json.dumps(json_safe(row), sort_keys=True) + "\n")
        except OSError as err:  # a full disk: the row may be torn, and is set aside by the next append
            raise write_error(err, self.path) from None

    def _set_torn_line_aside(self) -> None:
        """A metrics file whose last line has no newline (a write cut by a crash or a full disk, e.g. EFBIG): that
        line is appended to `metrics.jsonl.torn` and removed from the file; a complete row only gets its newline."""
        if not self.path.exists():
            return
        with self.path.open("rb") as handle:
            size = handle.seek(0, 2)
            handle.seek(max(0, size - TAIL_BYTES))
            tail = handle.read()
        if not tail or tail.endswith(b"\n"):
            return
        cut = tail.rfind(b"\n") + 1
        if cut == 0 and size > len(tail):
            raise MetricsError(f"{self.path}: its last line is longer than {TAIL_BYTES} bytes and has no "
                               "end; not appending to it")
        torn = tail[cut:]
        if _parse_row(torn) is not None:
            with self.path.open("ab") as handle:
                handle.write(b"\n")
            return
        with self.path.with_name(self.path.name + ".torn").open("ab") as aside:
            aside.write(torn + b"\n")
        os.truncate(self.path, size - len(torn))
        print(f"metrics: moved the torn last line of {self.path} ({len(torn)} bytes) to "
              f"{self.path.name}.torn", file=sys.stderr)

    def rows(self, kind: str | None = None) -> Iterator[dict[str, Any]]:
        """Metrics rows in order, optionally only those with row["kind"] == kind. A last line that does not parse
        (torn by a crash or a full disk) is left out and said once on stderr; a line that does not parse with rows
        after it raises MetricsError naming the file and the line."""
        if not self.path.exists():
            return
        self.check_file()
        bad: tuple[int, str] | None = None  # a line that did not parse, until it proves not to be the last
        with self.path.open("rb") as handle:
            for number, line in enumerate(handle, 1):
                if not line.strip():
                    continue
                if bad is not None:
                    raise MetricsError(f"{self.path} line {bad[0]}: {bad[1]}, with rows after it; refusing "
                                       "to read a corrupt metrics file")
                row = _parse_row(line)
                if row is None:
                    bad = (number, f"not a JSON object ({line[:40]!r})")
                elif kind is None or row.get("kind") == kind:
                    yield row
        if bad is not None and not self._torn_said:
            self._torn_said = True
            print(f"metrics: ignored the torn last line of {self.path} (line {bad[0]})", file=sys.stderr)

    def check_file(self) -> None:
        """MetricsError naming metrics.jsonl when something other than a file (a directory, ...) has its name."""
        if self.path.exists() and not self.path.is_file():
            kind = "a directory" if self.path.is_dir() else "not a regular file"
            raise MetricsError(f"{self.path} is {kind}, not the run's metrics file; move it away")

    def truncate_after(self, episodes: int) -> None:
        """On resume: drop rows logged after the checkpoint (row["episodes"] > episodes), atomically."""
        if not self.path.exists():
            return
        kept = [row for row in self.rows() if row.get("episodes", 0) <= episodes]
        atomic_write_bytes(self.path, "".join(json.dumps(r, sort_keys=True) + "\n" for r in kept).encode())

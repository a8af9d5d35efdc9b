"""A file of a run that cannot be written: a full disk, a quota, a read-only or failing device, a file-size limit.

Every writer of a run's files raises `RunWriteError` naming the file: `cmcl.io.atomic` (checkpoints, the replay's
snapshots, configs, summaries, the supervisor's counters), `cmcl.io.durable` (the replay log) and
`cmcl.io.metrics_log` (metrics rows). Both runners then end the run with one line naming the file and what is kept
(`write_failure_line`) instead of a traceback that names no file ("[Errno 28] No space left on device", found on
2026-12-06 with a run directory on a 1.5 MB tmpfs). What was written before stays as it was: an atomic write leaves
the old file, and a torn last metrics line or replay-log frame is set aside when the run is resumed.

Where it sits: storage (cmcl.io); it imports only the resume hint, so every writer can use it.
"""

from __future__ import annotations

import errno
import os

from cmcl.io.resume_hint import resume_command

# the device refused the write: no room (ENOSPC, EDQUOT), not writable (EROFS), failing (EIO), a size limit (EFBIG)
WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EIO, errno.EFBIG})


class RunWriteError(OSError):
    """OSError(errno, strerror, filename): writing `filename` failed because its device refused it (WRITE_ERRNOS);
    str(): "cannot write FILE: STRERROR", so any command that prints an error in one line names the file."""

    def __str__(self) -> str:
        return f"cannot write {self.filename}: {self.strerror}"


def write_error(err: OSError, path: str | os.PathLike) -> OSError:
    """`err` as a RunWriteError naming `path` when its errno says the device refused the write; else `err` itself."""
    if isinstance(err, RunWriteError) or err.errno not in WRITE_ERRNOS:
        return err
    return RunWriteError(err.errno, err.strerror or os.strerror(err.errno), os.fspath(path))


def write_failure_line(err: RunWriteError, run_path: str | os.PathLike, kept: str | None) -> str:
    """The one line that ends a run whose file could not be written; `kept`: what a resume starts from ("its last
    checkpoint"), None when there is nothing to resume from."""
    if kept is None:
        return f"{err}; no checkpoint was written yet; make room, then start the run again"
    return f"{err}; the run keeps {kept}; make room, then resume with: {resume_command(run_path)}"

"""One writer per run directory: an advisory lock (`flock`) on `<run dir>/run.lock`, naming its holder.

Where it sits: both runners (`python -m cmcl train | resume`) take it before they create, overwrite or resume a run
directory, and hold it until they exit; `python -m cmcl evaluate` only reads and takes none. The kernel drops the
lock when every process holding it has exited, by any signal (SIGKILL included), so a lock left by a dead process
never blocks: the file stays, but nothing holds it. A process that inherits the descriptor (the launcher's Ray
reaper, `services.runtime.reaper`) holds it too, so a new writer waits until the old run's last process has gone.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
import sys
import time
from pathlib import Path

LOCK_NAME = "run.lock"
DEAD_HOLDER_WAIT_S = 15.0  # how long to wait for the processes of a holder that has died (its reaper) to let go


class RunDirectoryInUse(RuntimeError):
    """Another live process holds the run directory; the message names it (pid, host, command, since when)."""


class RunLock:
    """The held lock of one run directory. `acquire` takes it or raises `RunDirectoryInUse`; `release` (or the
    process's exit) gives it back. `fd` is the open descriptor, for a child that must hold the lock as well."""

    def __init__(self, path: Path, fd: int, made_dir: bool = False):
        self.path, self.fd, self.made_dir = path, fd, made_dir

    @classmethod
    def acquire(cls, run_dir: str | Path, command: str | None = None) -> RunLock:
        """Lock `run_dir` (created if missing) for this process, without waiting.

        command: what to name this holder by in a refusal (default: this process's argv)."""
        directory = Path(run_dir)
        made_dir = not directory.exists()
        directory.mkdir(parents=True, exist_ok=True)
        path = directory / LOCK_NAME
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        deadline = time.monotonic() + DEAD_HOLDER_WAIT_S
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                # the named holder is dead but the lock is held: its reaper is still ending the old run's processes
                if not _holder_alive(path) and time.monotonic() < deadline:
                    time.sleep(0.1)
                    continue
                holder = _describe(path)
                if not _holder_alive(path):  # the named holder is gone; say which live process holds its lock
                    holder = _inheritors(path, holder)
                os.close(fd)
                raise RunDirectoryInUse(f"run directory {str(directory)!r} is in use by {holder}; wait for that run "
                                        f"to end or stop it (Ctrl-C), or choose another run.dir") from None
        holder = {"pid": os.getpid(), "host": socket.gethostname(), "since": time.strftime("%Y-%m-%d %H:%M:%S"),
                  "command": command or holder_command()}
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(holder).encode(), 0)
        return cls(path, fd, made_dir)

    def release(self) -> None:
        """Give the lock back (idempotent)."""
        if self.fd >= 0:
            fcntl.flock(self.fd, fcntl.LOCK_UN)
            os.close(self.fd)
            self.fd = -1

    def discard(self) -> None:
        """Remove the lock file while still holding it, then release it; remove the run directory too when
        `acquire` made it and it is now empty (a start that failed leaves no trace)."""
        if self.fd >= 0:
            self.path.unlink(missing_ok=True)
            self.release()
            if self.made_dir:
                with contextlib.suppress(OSError):
                    self.path.parent.rmdir()

    def __enter__(self) -> RunLock:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def holder_of(run_dir: str | Path) -> str | None:
    """Who holds the lock of `run_dir` now ("pid 123 on h since 2026-12-06 10:09:44"), None when no process does.
    Read only: the lock file is neither made nor written (a shared lock is tried and dropped at once; a start that
    meets it in that instant waits and retries, as for a dead holder)."""
    path = Path(run_dir) / LOCK_NAME
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    except BlockingIOError:
        try:
            holder = json.loads(path.read_text() or "{}")
            return f"pid {holder['pid']} on {holder['host']} since {holder['since']}"
        except (OSError, ValueError, KeyError, TypeError):
            return "holder unknown: its lock file is unreadable"
    finally:
        os.close(fd)


def holder_command() -> str:
    """This process's command line as a user typed it: `python -m cmcl resume runs/x` (the module
    name stands for the path Python puts in argv[0] under -m)."""
    main = sys.modules.get("__main__")
    spec = getattr(main, "__spec__", None)
    head = ["python", "-m", spec.name.removesuffix(".__main__")] if spec is not None else ["python", sys.argv[0]]
    return " ".join([*head, *sys.argv[1:]])


def _holder_alive(path: Path) -> bool:
    """Whether the process the lock file names still runs on this host (unknown holders count as alive)."""
    try:
        holder = json.loads(path.read_text() or "{}")
        if holder.get("host") != socket.gethostname():
            return True
        os.kill(int(holder["pid"]), 0)
        return True
    except ProcessLookupError:
        return False
    except (OSError, ValueError, KeyError, TypeError):
        return True


def _describe(path: Path) -> str:
    """'pid 123 on host h (python -m services.launch ..., since 2026-12-03 04:00:00)' from the lock file."""
    try:
        holder = json.loads(path.read_text() or "{}")
        return (f"pid {holder['pid']} on {holder['host']} ({holder['command']}, since {holder['since']})")
    except (OSError, ValueError, KeyError, TypeError):
        return f"another process (holder unknown: {path} unreadable)"


def _inheritors(path: Path, named: str) -> str:
    """Who holds the lock of `path` when the holder the file names has died: the live processes with the lock file
    open (found in /proc/*/fd: a child that inherited the descriptor, e.g. the Ray reaper), named with their
    command lines, and the dead holder they inherited it from."""
    target, found = os.path.realpath(path), []
    for entry in Path("/proc").iterdir() if Path("/proc").is_dir() else ():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            if any(os.path.realpath(fd) == target for fd in (entry / "fd").iterdir()):
                command = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace").strip()
                found.append(f"pid {entry.name} ({command[:120] or '?'})")
        except OSError:
            continue
    if not found:
        return f"a process this one cannot see (the lock's named holder, {named}, has ended)"
    return (f"{', '.join(found)}, which still hold{'s' if len(found) == 1 else ''} its lock: the run that took it, "
            f"{named}, has ended; wait for {'it' if len(found) == 1 else 'them'} to exit, or end "
            f"{'it' if len(found) == 1 else 'them'}")


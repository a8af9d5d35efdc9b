"""The embedded Ray's reaper: when the launcher dies, by any signal (SIGKILL included), no process it started lives on.

Where it sits: `services.launch` starts it (`start_reaper`) right before an embedded `ray.init`, as its own
session, with a pipe it never writes to and the run directory's lock descriptor. Ray ties its GCS and raylet to the
launcher, but not the raylet's own children (`ray::DashboardAgent`, `ray::RuntimeEnvAgent`): after a SIGKILL of the
launcher they were measured alive minutes later. The reaper records the launcher's descendants every
`POLL_S` seconds (pid and start time, so a reused pid is never touched); when the pipe reaches end of file (the
launcher has exited, however), it SIGKILLs every recorded process still alive, and their children, then exits,
which releases the run directory's lock it held (cmcl.run.runlock). Standard library only: it never imports Ray.

    python -m services.runtime.reaper LAUNCHER_PID      (stdin: the launcher's pipe)
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

POLL_S = 0.5  # seconds between scans of the launcher's descendants
KILL_ROUNDS = 20  # rounds of SIGKILL (every 0.1 s) for processes still alive after the launcher's exit


EXITED_STATES = ("Z", "X")  # /proc/<pid>/stat states of a process that has exited: zombie (awaiting a wait), dead


def process_table() -> dict[int, tuple[int, int]]:
    """{pid: (parent pid, start time in clock ticks since boot)} of every running process, from /proc/<pid>/stat.
    A zombie is left out: it has exited and only waits for its parent (or init, once that parent is gone) to read its
    status; no signal reaches it. Counting one as alive held the reaper (and the tests) ~2 s after every run."""
    table = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()  # after "pid (comm) ": state ppid ... starttime (field 22)
        if fields[0] not in EXITED_STATES:
            table[int(entry.name)] = (int(fields[1]), int(fields[19]))
    return table


def descendants(roots: set[int], table: dict[int, tuple[int, int]]) -> dict[int, int]:
    """{pid: start time} of every process below `roots` in `table` (the roots themselves excluded)."""
    children: dict[int, list[int]] = {}
    for pid, (ppid, _) in table.items():
        children.setdefault(ppid, []).append(pid)
    found, frontier = {}, list(roots)
    while frontier:
        for child in children.get(frontier.pop(), []):
            if child not in found:
                found[child] = table[child][1]
                frontier.append(child)
    return found


def reap(known: dict[int, int]) -> int:
    """SIGKILL every process of `known` ({pid: start time}) still alive with the same start time, and its
    descendants, until none is left (or KILL_ROUNDS rounds); returns how many were signalled."""
    signalled: set[int] = set()
    for _ in range(KILL_ROUNDS):
        table = process_table()
        alive = {pid for pid, start in known.items() if table.get(pid, (0, -1))[1] == start}
        targets = alive | set(descendants(alive, table))
        targets.discard(os.getpid())
        if not targets:
            break
        for pid in targets:
            try:
                os.kill(pid, signal.SIGKILL)
                signalled.add(pid)
            except ProcessLookupError:
                pass
        known.update(descendants(alive, table))
        time.sleep(0.1)
    return len(signalled)


def watch(launcher: int) -> int:
    """Record the launcher's descendants until stdin reaches end of file, then reap them; returns the count."""
    known: dict[int, int] = {}
    me = os.getpid()
    while True:
        table = process_table()
        known.update({pid: start for pid, start in descendants({launcher}, table).items() if pid != me})
        ready, _, _ = select.select([sys.stdin], [], [], POLL_S)
        if ready and not os.read(sys.stdin.fileno(), 4096):
            return reap(known)


def start_reaper(keep_fds: tuple[int, ...] = ()) -> subprocess.Popen:
    """Start the reaper of this process's descendants. It lives until this process has exited (its pipe closes
    then), in a session of its own so that a Ctrl-C to the terminal's process group does not reach it; `keep_fds`
    are passed on to it (the run directory's lock, so the lock outlives this process until the reaping is done)."""
    return subprocess.Popen([sys.executable, "-m", "services.runtime.reaper", str(os.getpid())], stdin=subprocess.PIPE,
                            start_new_session=True, pass_fds=keep_fds, close_fds=True,
                            cwd=str(Path(__file__).resolve().parents[1]))


def main() -> int:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    watch(int(sys.argv[1]))
    return 0


if __name__ == "__main__":
    sys.exit(main())

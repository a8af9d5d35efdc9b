"""The reaper's view of the process table (services/runtime/reaper.py): a process that has exited is not running, even
while it is a zombie waiting for its parent to read its status; one that runs is, with its parent and start time."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from services.runtime.reaper import descendants, process_table


def state(pid: int) -> str:
    """The state letter of /proc/<pid>/stat ('R', 'S', 'Z', ...)."""
    stat = Path(f"/proc/{pid}/stat").read_text()
    return stat[stat.rindex(")") + 2]


def test_a_zombie_is_not_running_and_a_sleeping_child_is():
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    exited = subprocess.Popen([sys.executable, "-c", "pass"])  # never waited for below until checked: a zombie
    try:
        deadline = time.monotonic() + 60
        while state(exited.pid) != "Z":  # polls the child's own state; the loop re-checks it
            assert time.monotonic() < deadline, "the child did not exit within 60 s"
            time.sleep(0.05)
        table = process_table()
        assert exited.pid not in table
        assert table[sleeper.pid][0] == os.getpid() and sleeper.pid in descendants({os.getpid()}, table)
    finally:
        sleeper.kill()
        sleeper.wait()
        exited.wait()


"""Fault injection for the fault tests and the recovery bench: find an actor's process in Ray's GCS actor table and
kill it with SIGKILL (a real kill: no cleanup, no Python exception, as a crash or the OOM killer would).

Where it sits: used by tests/test_service_faults.py and bench/recovery_times.py only; nothing in the service
imports it. The dashboard-backed `ray.util.state` API needs the dashboard, which the tests do not start; the GCS
actor table (`ray._private.state.actors`) is the same state without it.
"""

from __future__ import annotations

import os
import signal
import time
from typing import Any

import ray._private.state as gcs_state


def actor_entry(handle: Any) -> dict[str, Any]:
    """The GCS actor-table entry of an actor: State (ALIVE, RESTARTING, DEAD, ...), Pid, NumRestarts, Address."""
    return gcs_state.actors(handle._actor_id.hex())


def alive_pid(handle: Any, timeout_s: float = 60.0, exclude: frozenset[int] = frozenset()) -> int:
    """The pid of the actor's current process, once the GCS lists it ALIVE with a pid not in `exclude` (the
    processes killed before: waits out a restart in progress)."""
    deadline = time.monotonic() + timeout_s
    while True:
        entry = actor_entry(handle)
        if entry["State"] == "ALIVE" and entry.get("Pid") and int(entry["Pid"]) not in exclude:
            return int(entry["Pid"])
        if entry["State"] == "DEAD" or time.monotonic() > deadline:
            raise RuntimeError(f"actor {entry['ActorClassName']} is {entry['State']}, no process to kill")
        time.sleep(0.05)  # polling the GCS table; not a synchronisation stand-in: the loop checks the state


def sigkill_actor(handle: Any, timeout_s: float = 60.0, exclude: frozenset[int] = frozenset()) -> tuple[int, float]:
    """SIGKILL the actor's process, found through the GCS actor table (a pid not in `exclude`: never one killed
    before); returns (pid, monotonic time of the kill)."""
    pid = alive_pid(handle, timeout_s, exclude)
    os.kill(pid, signal.SIGKILL)
    return pid, time.monotonic()

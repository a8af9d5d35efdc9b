"""What bench/service_breakdown.py samples while the service runs, and the CPU arithmetic over its samples.

A `Sampler` thread takes, every SAMPLE_EVERY_S seconds until its deadline: the cumulative CPU seconds (user +
system, /proc via psutil) of this process and of every process it started, each one's command line and nice value
(read once), the machine's busy CPU seconds (all cores), and the supervisor's counters (learner updates, env steps,
the learner's busy wall and CPU seconds, the HeldClock's seconds by reason). Times are `time.perf_counter()`
seconds. The helpers turn those cumulative samples into CPU seconds over a window [t0, t1] and into cores used.
"""

from __future__ import annotations

import threading
import time
from bisect import bisect_right
from dataclasses import dataclass, field
from typing import Any

import psutil

SAMPLE_EVERY_S = 1.0


def cpu_between(samples: list[tuple[float, float]], t0: float, t1: float) -> float:
    """CPU seconds a process used in [t0, t1] from its (time, cumulative CPU s) samples, in time order: the last
    sample at or before t1 minus the last at or before t0 (0 when the process was first seen after t0: it started
    in the window). 0 when no sample falls at or before t1."""
    times = [t for t, _ in samples]
    end = bisect_right(times, t1) - 1
    if end < 0:
        return 0.0
    start = bisect_right(times, t0) - 1
    return max(0.0, samples[end][1] - (samples[start][1] if start >= 0 else 0.0))


def core_shares(cpu_s: float, window_s: float, cores: int) -> tuple[float, float]:
    """(cores used: CPU s per wall s, share of all `cores`) of `cpu_s` CPU seconds over `window_s` seconds."""
    if window_s <= 0 or cores <= 0:
        raise ValueError(f"window_s and cores must be > 0, got {window_s!r}, {cores!r}")
    return cpu_s / window_s, cpu_s / (window_s * cores)


def machine_busy(times: Any) -> float:
    """CPU seconds the machine's cores spent busy (psutil.cpu_times(): user, nice, system, irq, softirq, steal; guest
    time is already inside user and nice)."""
    return sum(getattr(times, key, 0.0) for key in ("user", "nice", "system", "irq", "softirq", "steal"))


@dataclass
class Sample:
    """One sample of the service's counters (learner: cumulative from its reports; held: the HeldClock)."""

    t: float
    updates: float
    env_steps: float
    busy_s: float
    busy_cpu_s: float
    held: dict[str, float]
    machine_busy_s: float  # CPU seconds of the whole machine (all cores) so far, every process


@dataclass
class Sampler:
    """Samples every SAMPLE_EVERY_S the CPU times of this process's descendants and the supervisor's counters, until
    `deadline` (perf_counter), in a thread."""

    supervisor: Any
    deadline: float
    cpu: dict[int, list[tuple[float, float]]] = field(default_factory=dict)  # pid -> [(t, CPU s)]
    cmdline: dict[int, str] = field(default_factory=dict)
    nice: dict[int, int] = field(default_factory=dict)
    samples: list[Sample] = field(default_factory=list)
    own_cpu: list[tuple[float, float]] = field(default_factory=list)  # (t, this thread's CPU s)

    def __post_init__(self) -> None:
        self._thread = threading.Thread(target=self._loop, daemon=True, name="breakdown-sampler")
        self._procs: dict[int, psutil.Process] = {}

    def start(self) -> None:
        self._thread.start()

    def join(self) -> None:
        self._thread.join()

    def _loop(self) -> None:
        while True:
            now = time.perf_counter()
            self._sample(now)
            if now >= self.deadline:
                return
            time.sleep(max(0.0, min(SAMPLE_EVERY_S, self.deadline - time.perf_counter())))

    def _sample(self, now: float) -> None:
        me = psutil.Process()
        for proc in [me, *me.children(recursive=True)]:
            proc = self._procs.setdefault(proc.pid, proc)
            try:
                times = proc.cpu_times()
                if proc.pid not in self.cmdline:
                    self.cmdline[proc.pid] = " ".join(proc.cmdline()) or proc.name()
                    self.nice[proc.pid] = proc.nice()
            except psutil.Error:
                continue
            self.cpu.setdefault(proc.pid, []).append((now, times.user + times.system))
        sup, machine = self.supervisor, psutil.cpu_times()
        value = sup.metrics.value
        self.samples.append(Sample(
            t=now, updates=value("cmcl_learner_updates_total") or 0.0, env_steps=value("cmcl_env_steps_total") or 0.0,
            busy_s=value("cmcl_learner_busy_seconds_total") or 0.0,
            busy_cpu_s=value("cmcl_learner_busy_cpu_seconds_total") or 0.0, held=dict(sup.held.seconds),
            machine_busy_s=machine_busy(machine)))
        self.own_cpu.append((now, time.thread_time()))

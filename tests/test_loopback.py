"""A local service run listens on the loopback interface only: the launcher and every process below it (the
embedded Ray's GCS, raylet, agents, and the actors' workers), listed from the kernel's socket table while the run
trains, and the tests' session Ray likewise (services/runtime/loopback.py)."""

from __future__ import annotations

import ipaddress
import signal
import sys

import psutil
import pytest

from tests.test_user_path import Launched

PY = sys.executable


def non_loopback_listeners(root: int) -> list[str]:
    """Every TCP socket listening on an address other than loopback (127.0.0.0/8, ::1, ::ffff:127.x) held by process
    `root` or a process below it, as "name pid address:port"."""
    try:
        procs = [psutil.Process(root), *psutil.Process(root).children(recursive=True)]
    except psutil.NoSuchProcess:
        return []
    found = []
    for proc in procs:
        try:
            listening = [c for c in proc.net_connections("inet") if c.status == psutil.CONN_LISTEN]
            name = proc.name()
        except psutil.NoSuchProcess:
            continue
        for conn in listening:
            address = ipaddress.ip_address(conn.laddr.ip.split("%")[0])
            mapped = getattr(address, "ipv4_mapped", None)
            if not (address.is_loopback or (mapped is not None and mapped.is_loopback)):
                found.append(f"{name} {proc.pid} {conn.laddr.ip}:{conn.laddr.port}")
    return found


def listener_count(root: int) -> int:
    """How many TCP sockets process `root` and the processes below it listen on."""
    procs = [psutil.Process(root), *psutil.Process(root).children(recursive=True)]
    count = 0
    for proc in procs:
        try:
            count += sum(c.status == psutil.CONN_LISTEN for c in proc.net_connections("inet"))
        except psutil.NoSuchProcess:
            continue
    return count


def test_a_local_service_run_listens_on_loopback_only(tmp_path):
    run = Launched([PY, "-m", "cmcl", "train", "--runner", "service", "--config", "configs/smoke.toml",
                    "--set", f"run.dir={tmp_path / 'run'}", "--set", "run.episodes=100000",
                    "--set", "run.max_seconds=120", "--metrics-port", "0", "--no-eval"])
    try:
        run.wait_for(lambda line: line.startswith("ep "), "the first progress line (every role is up)")
        assert listener_count(run.proc.pid) >= 5, "expected Ray's servers among the launcher's processes"
        assert non_loopback_listeners(run.proc.pid) == []
    finally:
        run.proc.send_signal(signal.SIGINT)
        run.finish()


@pytest.mark.ray
def test_the_session_ray_listens_on_loopback_only(ray_cluster):
    @ray_cluster.remote
    class Probe:
        def ping(self) -> int:
            return 1

    probe = Probe.remote()
    assert ray_cluster.get(probe.ping.remote()) == 1  # an actor's gRPC server is up too
    assert non_loopback_listeners(psutil.Process().pid) == []

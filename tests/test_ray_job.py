"""The cluster path for real: `ray start --head` on loopback with token authentication on, then the launch submitted
with `ray job submit -- python -m services.launch --address auto ...` (a short budget), which must finish and have
trained. A submission with a wrong token is refused.

The head runs as `ray start --head --block` in its own process group and is stopped by signalling that group
(never `ray stop`, which would stop every Ray on the machine, the test session's own included). Every port the
head opens is chosen free, so that it never collides with another Ray on the machine (the session's included).
"""

from __future__ import annotations

import os
import re
import secrets
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.ports import free_port

ROOT = Path(__file__).resolve().parents[1]
RAY = Path(sys.executable).parent / "ray"
pytestmark = pytest.mark.ray


def listening(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


@pytest.fixture
def head(tmp_path):
    """A token-auth Ray head on loopback: yields (dashboard address, environment with the token)."""
    token = secrets.token_hex(16)
    env = {**os.environ, "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": token}
    gcs, dashboard, agent, agent_grpc = free_port(), free_port(), free_port(), free_port()
    proc = subprocess.Popen(
        [str(RAY), "start", "--head", "--block", "--node-ip-address=127.0.0.1", f"--port={gcs}",
         "--num-cpus=2", "--include-dashboard=true", "--dashboard-host=127.0.0.1", f"--dashboard-port={dashboard}",
         # the dashboard agent's HTTP port defaults to 52365 for every Ray on the machine: the test session's own
         # Ray holds it, and an agent that cannot bind it leaves the job API answering "No available agent"
         f"--dashboard-agent-listen-port={agent}", f"--dashboard-agent-grpc-port={agent_grpc}",
         # on SIGTERM `ray start --block` first drains the node for Ray Serve, up to 30 s by default; nothing here
         # serves (the job has finished), so the head stops at once
         "--disable-usage-stats"], env={**env, "RAY_GRACEFUL_SHUTDOWN_DRAIN_TIMEOUT_S": "0"}, cwd=tmp_path,
        stdout=open(tmp_path / "head.log", "w"),
        stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while not listening(dashboard):  # the dashboard's port opens once the head is up
            assert proc.poll() is None, (tmp_path / "head.log").read_text()[-3000:]
            assert time.monotonic() < deadline, "the Ray head did not open its dashboard port within 120 s"
            time.sleep(0.5)  # polling a port; the loop re-checks the condition itself
        yield f"http://127.0.0.1:{dashboard}", env
    finally:
        os.killpg(proc.pid, signal.SIGTERM)  # `ray start --block` stops the processes it started
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


# out of the default run (its 10-minute budget): starts a cluster of its own
@pytest.mark.extended
def test_ray_job_submit_runs_the_launch_on_a_token_auth_cluster(head, tmp_path):
    address, env = head
    run_dir = tmp_path / "job-run"
    entrypoint = (f"cd {ROOT} && {sys.executable} -m services.launch --address auto "
                  f"--config configs/smoke.toml --set run.dir={run_dir} --set run.episodes=32 --metrics-port 0 "
                  "--overwrite --quiet --no-eval")
    deadline = time.monotonic() + 120
    while True:  # the dashboard port opens before its job agent has registered: Ray answers "No available agent"
        submit = [str(RAY), "job", "submit", f"--address={address}", "--", "bash", "-c", entrypoint]
        done = subprocess.run(submit, env=env, capture_output=True, text=True, timeout=420)
        if "No available agent" not in done.stdout + done.stderr or time.monotonic() > deadline:
            break
        time.sleep(2.0)  # then submit again: the loop re-checks Ray's answer
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert re.search(r"done: \d+ episodes", done.stdout), done.stdout[-3000:]
    assert "succeeded" in done.stdout.lower(), done.stdout[-2000:]
    assert (run_dir / "metrics.jsonl").exists() and (run_dir / "checkpoints" / "service" / "learner.pt.manifest.json"
                                                     ).exists(), "the job trained and checkpointed"
    wrong = {**env, "RAY_AUTH_TOKEN": "not-the-token-" + secrets.token_hex(4)}
    refused = subprocess.run([str(RAY), "job", "list", f"--address={address}"], env=wrong, capture_output=True,
                             text=True, timeout=120)
    assert refused.returncode != 0, "a client with a wrong token is refused"

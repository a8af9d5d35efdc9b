"""Security defaults: the launcher's embedded Ray has token authentication on, and refuses a client without it. The
same probe (one embedded Ray, started and stopped as the launcher does) checks how the launcher stops that Ray."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.ray


@pytest.fixture(scope="module")
def probe() -> dict:
    """The JSON line of `python -m tests.auth_probe`."""
    done = subprocess.run([sys.executable, "-m", "tests.auth_probe"], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_the_embedded_ray_refuses_a_client_with_a_wrong_token(probe):
    assert probe["token_auth"] is True and probe["mode"] == "token", probe
    assert probe["wrong_token"].startswith("refused"), probe
    assert probe["cluster_token"] == "joined", probe


def test_the_launcher_stops_its_embedded_ray_at_once_and_leaves_none_of_its_processes(probe):
    """Ray's own shutdown gives each process a 1 s SIGTERM grace, one after the other; the embedded Ray's processes
    have SIGTERM blocked (services.launch.start_ray), so that path takes at least 1 s per process."""
    assert probe["ray_processes"] >= 3 and probe["left"] == [], probe
    assert probe["stop_s"] < probe["ray_processes"] * 1.0, probe

"""Security defaults: the launcher's embedded Ray has token authentication on, and refuses a client without it."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.ray


def test_the_embedded_ray_refuses_a_client_with_a_wrong_token():
    done = subprocess.run([sys.executable, "-m", "tests.auth_probe"], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["token_auth"] is True and result["mode"] == "token", result
    assert result["wrong_token"].startswith("refused"), result
    assert result["cluster_token"] == "joined", result

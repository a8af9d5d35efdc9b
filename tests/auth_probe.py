"""Whether the launcher's embedded Ray refuses a client without its token. Run as its own process (it starts its own
Ray the way `python -m services.launch` does):

    python -m tests.auth_probe      # prints one JSON line

Two client processes join the cluster's GCS: one with a wrong token (RAY_AUTH_TOKEN), which must be refused,
and one with the token the cluster generated (~/.ray/auth_token), which must join.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

JOIN = """
import sys
import ray
try:
    ray.init(address=sys.argv[1], log_to_driver=False)
    print("joined")
except Exception as err:  # noqa: BLE001 - any refusal is the answer
    print("refused:", type(err).__name__)
"""


def join(gcs: str, env: dict[str, str]) -> str:
    """'joined' or 'refused: <error type>' for one client process joining `gcs` with `env`."""
    done = subprocess.run([sys.executable, "-c", JOIN, gcs], env=env, capture_output=True, text=True, timeout=120)
    return (done.stdout.strip().splitlines() or ["no answer: " + done.stderr[-300:]])[-1]


def main() -> dict:
    import ray
    from ray._private.authentication.authentication_utils import is_token_auth_enabled

    from services.launch import start_ray

    start_ray(None, 1)
    try:
        gcs = ray.get_runtime_context().gcs_address
        base = {k: v for k, v in os.environ.items() if not k.startswith("RAY_AUTH_TOKEN")}
        return {"token_auth": is_token_auth_enabled(), "mode": os.environ.get("RAY_AUTH_MODE"),
                "wrong_token": join(gcs, {**base, "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": "not-the-token-1234"}),
                "cluster_token": join(gcs, base)}
    finally:
        ray.shutdown()


if __name__ == "__main__":
    print(json.dumps(main()), flush=True)

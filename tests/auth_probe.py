"""Whether the launcher's embedded Ray refuses a client without its token, and how it stops. Run as its own process
(it starts and stops its own Ray the way `python -m services.launch` does):

    python -m tests.auth_probe      # prints one JSON line

Two client processes join the cluster's GCS at the same time: one with a wrong token (RAY_AUTH_TOKEN), which must
be refused, and one with the token the cluster generated (~/.ray/auth_token), which must join. Then the launcher's
`stop_ray`: its seconds, how many processes Ray had started, and those still running after it returned.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

JOIN = """
import sys
import ray
try:
    ray.init(address=sys.argv[1], log_to_driver=False)
    print("joined")
except Exception as err:  # noqa: BLE001 - any refusal is the answer
    print("refused:", type(err).__name__)
"""


def start_join(gcs: str, env: dict[str, str]) -> subprocess.Popen:
    """A client process joining `gcs` with `env` (see `answer`)."""
    return subprocess.Popen([sys.executable, "-c", JOIN, gcs], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def answer(client: subprocess.Popen) -> str:
    """'joined' or 'refused: <error type>' of a client from `start_join`."""
    out, err = client.communicate(timeout=120)
    return (out.strip().splitlines() or ["no answer: " + err[-300:]])[-1]


def main() -> dict:
    import ray
    from ray._private import worker
    from ray._private.authentication.authentication_utils import is_token_auth_enabled

    from services.launch import start_ray, stop_ray
    from services.runtime.reaper import process_table

    start_ray(None, 1)
    try:
        gcs = ray.get_runtime_context().gcs_address
        base = {k: v for k, v in os.environ.items() if not k.startswith("RAY_AUTH_TOKEN")}
        wrong = start_join(gcs, {**base, "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": "not-the-token-1234"})
        right = start_join(gcs, base)
        result = {"token_auth": is_token_auth_enabled(), "mode": os.environ.get("RAY_AUTH_MODE"),
                  "wrong_token": answer(wrong), "cluster_token": answer(right)}
    finally:
        started = {p.process.pid for infos in worker._global_node.all_processes.values() for p in infos}
        began = time.monotonic()
        stop_ray()
        stopped_s = time.monotonic() - began
    return {**result, "stop_s": stopped_s, "ray_processes": len(started),
            "left": sorted(started & set(process_table()))}


if __name__ == "__main__":
    print(json.dumps(main()), flush=True)

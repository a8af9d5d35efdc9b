"""docker-compose.yml brought up for real by podman and podman-compose (`make test-deploy`; marker `deploy`, kept
out of the default `make test`).

`make test-deploy` builds the images first (deploy/build_base.sh, deploy/wheelhouse.sh, `podman-compose build`);
this module starts the Ray head (which runs the launcher), one Ray worker and Prometheus from the compose file,
with the podman settings of deploy/podman/containers.conf (CONTAINERS_CONF), host ports picked free and the run
directory in a temporary directory. It asserts that the worker joined the head and hosts the rollout workers, the
service trains (episodes and updates rise on its metrics endpoint), the compose healthcheck passes, Prometheus
scrapes the service, the Ray head and the Ray worker (found by DNS), the console dashboard renders live data in
headless Chromium on the host, and that `podman-compose down -v` leaves no container, volume or network behind.
Grafana is not started: its image comes from Docker Hub, which this machine cannot reach.

Without podman / podman-compose / chromium the module is skipped, or fails when CMCL_DEPLOY_STRICT=1 (what
`make test-deploy` sets). Every wait polls a condition with a deadline.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

import pytest

from tests.console_dom import CHROMIUM_FLAGS, check_console_dom
from tests.ports import free_port

ROOT = Path(__file__).resolve().parents[1]
PODMAN, COMPOSE, CHROMIUM = shutil.which("podman"), shutil.which("podman-compose"), shutil.which("chromium")
MISSING = [name for name, path in (("podman", PODMAN), ("podman-compose", COMPOSE), ("chromium", CHROMIUM))
           if path is None]
if MISSING and os.environ.get("CMCL_DEPLOY_STRICT") == "1":
    raise RuntimeError(f"make test-deploy needs {', '.join(MISSING)} (apt-get install podman podman-compose ...)")
pytestmark = [pytest.mark.deploy, pytest.mark.timeout(900),
              pytest.mark.skipif(bool(MISSING), reason=f"not installed: {', '.join(MISSING)} (make test-deploy)")]
SERVICES = ["cmcl-head", "cmcl-worker", "prometheus"]  # grafana: no image registry reachable here
IMAGES = ["cmcl-service:0.1.0", "cmcl-prometheus:2.42"]
WAIT_S = 300  # per condition; the stack shares 2 CPUs with other work


def run(*args: str, timeout: float = 120, check: bool = True, env: dict | None = None) -> str:
    result = subprocess.run(args, capture_output=True, text=True, timeout=timeout, env=env)
    if check and result.returncode:
        raise AssertionError(f"{' '.join(args)} -> {result.returncode}\n{result.stdout[-3000:]}\n"
                             f"{result.stderr[-3000:]}")
    return result.stdout


class Stack:
    """One compose project (its own name, host ports and run directory) and how to look inside it."""

    def __init__(self, tmp: Path):
        self.project = f"cmcl-deploytest-{os.getpid()}"
        self.prometheus_port, self.dashboard_port = free_port(), free_port()
        self.runs = tmp / "runs"
        self.runs.mkdir()
        if os.geteuid() == 0:
            os.chown(self.runs, 1000, 1000)  # the image's user cmcl writes there
        else:
            self.runs.chmod(0o777)
        self.env = {**os.environ, "CMCL_RAY_TOKEN": os.urandom(16).hex(), "CMCL_RUNS_DIR": str(self.runs),
                    "CMCL_PROMETHEUS_PORT": str(self.prometheus_port),
                    "CMCL_RAY_DASHBOARD_PORT": str(self.dashboard_port),
                    # long enough that the run outlasts the checks however fast the machine; ended by `down`
                    "CMCL_LAUNCH_ARGS": "--set run.episodes=10000000 --set run.max_seconds=1800"}
        self.log = tmp / "compose.log"
        self.timings: dict[str, float] = {}
        self.down_result: dict | None = None

    def compose(self, *args: str, timeout: float = 600) -> str:
        out = run(COMPOSE, "-p", self.project, *args, timeout=timeout, env=self.env)
        with self.log.open("a") as log:
            log.write(out)
        return out

    def container(self, service: str) -> str:
        return f"{self.project}_{service}_1"

    def running(self) -> set[str]:
        out = run(PODMAN, "ps", "--filter", f"label=io.podman.compose.project={self.project}", "--format",
                  "{{.Names}}")
        return set(out.split())

    def exec_python(self, code: str, timeout: float = 60) -> str:
        return run(PODMAN, "exec", self.container("cmcl-head"), "python", "-c", code, timeout=timeout)

    def wait_for(self, what: str, probe, deadline_s: float = WAIT_S):
        """Poll `probe()` (truthy = done) until the deadline; every container must keep running meanwhile."""
        deadline = time.monotonic() + deadline_s
        last: object = None
        while time.monotonic() < deadline:
            gone = {self.container(s) for s in SERVICES} - self.running()
            if gone:
                logs = {c: run(PODMAN, "logs", "--tail", "30", c, check=False) for c in gone}
                raise AssertionError(f"containers stopped before {what}: {sorted(gone)}\n{logs}")
            try:
                last = probe()
            except (AssertionError, urllib.error.URLError, ConnectionError, subprocess.TimeoutExpired) as error:
                last = error
            if last and not isinstance(last, Exception):
                return last
            time.sleep(2.0)  # between polls of the condition itself
        raise AssertionError(f"not within {deadline_s} s: {what} (last: {last!r})")

    def prometheus(self, path: str, **params: str) -> dict:
        url = f"http://127.0.0.1:{self.prometheus_port}/api/v1/{path}"
        data = json.loads(urllib.request.urlopen(f"{url}?{urllib.parse.urlencode(params)}", timeout=10).read())
        assert data["status"] == "success", data
        return data["data"]

    def leftovers(self) -> dict[str, list[str]]:
        label = f"label=io.podman.compose.project={self.project}"
        return {"containers": run(PODMAN, "ps", "-a", "--filter", label, "--format", "{{.Names}}").split(),
                "volumes": run(PODMAN, "volume", "ls", "--filter", label, "--format", "{{.Name}}").split(),
                "networks": [n for n in run(PODMAN, "network", "ls", "--format", "{{.Name}}").split()
                             if n.startswith(self.project)]}

    def down(self) -> dict:
        """`podman-compose down -v`; what it left; then the network it leaves (podman-compose 1.0.3) removed."""
        if self.down_result is None:
            start = time.monotonic()
            self.compose("down", "-v", timeout=300)
            left = self.leftovers()
            for network in left["networks"]:
                run(PODMAN, "network", "rm", network, check=False)
            self.down_result = {"after_compose_down": left, "after_network_rm": self.leftovers()}
            self.timings["down_s"] = round(time.monotonic() - start, 1)
        return self.down_result


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    for image in IMAGES:
        assert subprocess.run([PODMAN, "image", "exists", image], timeout=60).returncode == 0, (
            f"{image} not built: `make test-deploy` builds it")
    stack = Stack(tmp_path_factory.mktemp("compose"))
    start = time.monotonic()
    try:
        stack.compose("up", "-d", *SERVICES)
        stack.timings["up_s"] = round(time.monotonic() - start, 1)
        yield stack
    finally:
        stack.down()
        print(f"\ncompose stack {stack.project}: {json.dumps(stack.timings)}; log {stack.log}")


def metrics(stack: Stack) -> dict[str, float]:
    """The service's own endpoint, read inside the head container (port 9100 is not published to the host)."""
    text = stack.exec_python("import urllib.request; print(urllib.request.urlopen("
                             "'http://127.0.0.1:9100/metrics', timeout=5).read().decode())")
    return {m.group(1): float(m.group(2)) for m in re.finditer(r"^(cmcl_[a-z_]+) ([-0-9.e+]+)$", text, re.M)}


def test_the_worker_joins_the_head_and_hosts_the_rollout_workers(stack):
    code = """
import collections, json, ray
from ray.util.state import list_actors
ray.init(address="auto", logging_level="ERROR", log_to_driver=False)
nodes = {n["NodeID"]: n["NodeManagerHostname"] for n in ray.nodes() if n["Alive"]}
actors = collections.defaultdict(list)
for a in list_actors(filters=[("state", "=", "ALIVE")], limit=1000):
    actors[nodes.get(a.node_id, "?")].append(a.class_name)
print(json.dumps({"nodes": sorted(nodes.values()), "actors": actors}))
"""

    def placed():
        found = json.loads(stack.exec_python(code).strip().splitlines()[-1])
        (worker,) = set(found["nodes"]) - {"cmcl-head"} or {None}
        ok = (len(found["nodes"]) == 2 and set(found["actors"].get(worker, [])) == {"RolloutWorker"}
              and {"Learner", "ReplayServer"} <= set(found["actors"].get("cmcl-head", [])))
        return found if ok else None

    start = time.monotonic()
    stack.wait_for("2 Ray nodes: learner and replay on the head, only rollout workers on the worker", placed)
    stack.timings["cluster_s"] = round(time.monotonic() - start + stack.timings["up_s"], 1)


def test_the_service_trains_episodes_and_updates_rise(stack):
    first = stack.wait_for("the service's metrics endpoint answers with episodes",
                           lambda: (m := metrics(stack)).get("cmcl_episodes_total", 0) > 0 and m)

    def risen():
        now = metrics(stack)
        return now if all(now[k] > first[k] for k in ("cmcl_episodes_total", "cmcl_learner_updates_total")) else None

    now = stack.wait_for("episodes and learner updates rise", risen)
    assert now["cmcl_env_steps_total"] > first["cmcl_env_steps_total"]


def test_the_compose_healthcheck_passes(stack):
    # podman runs healthchecks from systemd timers, absent here: run the compose file's check by hand.
    stack.wait_for("the head's healthcheck passes", lambda: subprocess.run(
        [PODMAN, "healthcheck", "run", stack.container("cmcl-head")], capture_output=True, timeout=60).returncode == 0)


def test_prometheus_scrapes_the_service_the_ray_head_and_the_ray_worker(stack):
    def all_up():
        targets = stack.prometheus("targets", state="active")["activeTargets"]
        health = {t["labels"]["job"]: t["health"] for t in targets}
        return health if health == {"cmcl": "up", "ray-head": "up", "ray-workers": "up"} else None

    stack.wait_for("the cmcl, ray-head and ray-workers targets all up", all_up)
    for job, expr in (("cmcl", 'cmcl_learner_updates_total{job="cmcl"}'),
                      ("ray-workers", 'count({job="ray-workers", __name__=~"ray_.+"})'),
                      ("ray-head", 'count({job="ray-head", __name__=~"ray_.+"})')):
        result = stack.wait_for(f"{job} samples in Prometheus",
                                lambda e=expr: stack.prometheus("query", query=e)["result"])
        assert float(result[0]["value"][1]) > 0, (job, result)


def test_the_console_dashboard_renders_live_data_in_chromium(stack):
    stack.wait_for("a rate over 30 s in Prometheus", lambda: stack.prometheus(
        "query", query="rate(cmcl_learner_updates_total[30s]) > 0")["result"])
    url = f"http://127.0.0.1:{stack.prometheus_port}/consoles/cmcl.html?range=300"
    dom = subprocess.run([CHROMIUM, *CHROMIUM_FLAGS, "--dump-dom", url], capture_output=True, text=True,
                         timeout=120).stdout
    check_console_dom(dom)


def test_every_container_has_the_compose_files_memory_limit(stack):
    limits = {service: int(run(PODMAN, "inspect", "--format", "{{.HostConfig.Memory}}", stack.container(service)))
              for service in SERVICES}
    assert limits == {"cmcl-head": 6 << 30, "cmcl-worker": 3 << 30, "prometheus": 1 << 30}, limits


def test_the_published_ray_dashboard_wants_the_token(stack):
    url = f"http://127.0.0.1:{stack.dashboard_port}/api/jobs/"

    def status(token: str | None) -> int:
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        try:
            return urllib.request.urlopen(urllib.request.Request(url, headers=headers), timeout=10).status
        except urllib.error.HTTPError as error:
            return error.code

    assert stack.wait_for("the Ray dashboard answers with the token",
                          lambda: status(stack.env["CMCL_RAY_TOKEN"]) == 200)
    assert (status(None), status("0" * 32)) == (401, 403)


def test_compose_down_leaves_no_container_volume_or_network(stack):
    result = stack.down()
    assert result["after_network_rm"] == {"containers": [], "volumes": [], "networks": []}, result
    left = result["after_compose_down"]
    assert left["containers"] == [] and left["volumes"] == [], result
    # podman-compose 1.0.3 does not remove the project network (`docker compose down` does): removed above.
    assert left["networks"] in ([], [f"{stack.project}_default"]), result

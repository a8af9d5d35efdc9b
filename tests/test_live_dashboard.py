"""The service watched live by a real Prometheus (the Debian package) and its console dashboard opened in a real
headless Chromium (the Debian package). `make test` installs both where it can (root + apt-get); elsewhere these
tests are skipped, saying why.

One service run (CMCL, embedded Ray in its own process) is scraped by Prometheus, configured from
deploy/prometheus.yml with its targets rewritten to this test's ports (the service endpoint and Ray's own metrics
port) and a 1 s scrape interval. The tests then query Prometheus' HTTP API, check that every expression of both
dashboards names a metric the live endpoint exports, and render deploy/prometheus/consoles/cmcl.html in Chromium
(DOM and screenshot). CMCL_SCREENSHOT=path copies the screenshot there, after CMCL_SCREENSHOT_WAIT_S more seconds
of training (default 0): how docs/dashboard.png was made.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

import pytest
import yaml
from prometheus_client.parser import text_string_to_metric_families

from tests.console_dom import CHROMIUM_FLAGS, check_console_dom
from tests.ports import free_port

ROOT = Path(__file__).resolve().parents[1]
DEPLOY = ROOT / "deploy"
PROMETHEUS, CHROMIUM = shutil.which("prometheus"), shutil.which("chromium")
pytestmark = [pytest.mark.ray, pytest.mark.skipif(
    PROMETHEUS is None, reason="the Debian package prometheus is not installed (make test installs it as root)")]
SERVICE_BUDGET_S = 420  # the service stops by itself after this; the fixture stops it sooner (SIGINT)
WAIT_S = 150  # for each condition on what Prometheus has scraped (and the screenshot wait below it)


def get(url: str, timeout: float = 10.0) -> str:
    return urllib.request.urlopen(url, timeout=timeout).read().decode()


def prometheus_config(service_port: int, ray_port: int) -> dict:
    """deploy/prometheus.yml with the compose targets rewritten to this test's loopback ports."""
    config = yaml.safe_load((DEPLOY / "prometheus.yml").read_text())
    config["global"]["scrape_interval"] = "1s"
    jobs = {job["job_name"]: job for job in config["scrape_configs"]}
    jobs["cmcl"]["static_configs"][0]["targets"] = [f"127.0.0.1:{service_port}"]
    jobs["ray-head"]["static_configs"][0]["targets"] = [f"127.0.0.1:{ray_port}"]
    del jobs["ray-workers"]  # found by compose DNS; no worker nodes here
    config["scrape_configs"] = list(jobs.values())
    return config


class Live:
    """The running service and Prometheus: where they listen, and how to ask Prometheus."""

    def __init__(self, service_port: int, ray_port: int, prometheus_port: int, service: subprocess.Popen):
        self.service_port, self.ray_port, self.prometheus_port, self.service = (service_port, ray_port,
                                                                                 prometheus_port, service)
        self.started = time.monotonic()
        self.api = f"http://127.0.0.1:{prometheus_port}/api/v1"

    def query(self, expr: str) -> list[dict]:
        """The instant vector of `expr` now."""
        data = json.loads(get(f"{self.api}/query?" + urllib.parse.urlencode({"query": expr})))
        assert data["status"] == "success", data
        return data["data"]["result"]

    def wait_for(self, expr: str, what: str) -> list[dict]:
        """Poll Prometheus until `expr` returns a sample (the service still running), or fail naming `what`."""
        deadline = time.monotonic() + WAIT_S
        while time.monotonic() < deadline:
            assert self.service.poll() is None, f"the service ended before {what}"
            try:
                result = self.query(expr)
            except urllib.error.URLError:  # Prometheus still starting
                result = []
            if result:
                return result
            time.sleep(1.0)  # polling Prometheus' API; each pass re-checks the condition itself
        raise AssertionError(f"no sample for {expr!r} within {WAIT_S} s: {what}")


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("live")
    service_port, ray_port, prometheus_port = free_port(), free_port(), free_port()
    service = subprocess.Popen(
        [sys.executable, "-m", "services.launch", "--config", str(ROOT / "configs" / "spread_cmcl.toml"),
         "--set", f"run.dir={tmp / 'run'}", "--set", "run.episodes=200000", "--set",
         f"run.max_seconds={SERVICE_BUDGET_S}", "--metrics-port", str(service_port), "--ray-metrics-port",
         str(ray_port), "--overwrite", "--quiet", "--no-eval"], cwd=ROOT, stdout=subprocess.DEVNULL,
        stderr=open(tmp / "service.log", "w"))
    (tmp / "prometheus.yml").write_text(yaml.safe_dump(prometheus_config(service_port, ray_port)))
    prometheus = subprocess.Popen(
        [PROMETHEUS, f"--config.file={tmp / 'prometheus.yml'}", f"--storage.tsdb.path={tmp / 'tsdb'}",
         f"--web.listen-address=127.0.0.1:{prometheus_port}",
         f"--web.console.templates={DEPLOY / 'prometheus' / 'consoles'}",
         f"--web.console.libraries={DEPLOY / 'prometheus' / 'console_libraries'}"],
        stdout=subprocess.DEVNULL, stderr=open(tmp / "prometheus.log", "w"))
    try:
        live = Live(service_port, ray_port, prometheus_port, service)
        live.wait_for('up{job="cmcl"} == 1', "Prometheus scraped the service endpoint")
        live.wait_for("cmcl_replay_size > 0", "the buffer filled")
        live.wait_for("rate(cmcl_replay_inserts_total[30s]) > 0", "an insert rate over 30 s")
        live.wait_for("delta(cmcl_curriculum_lambda[30s]) > 0", "λ increased")
        live.wait_for("rate(cmcl_learner_updates_total[30s]) > 0 and cmcl_teacher_score_coverage > 0",
                      "the learner and the teachers at work")
        yield live
    finally:
        for proc in (service, prometheus):
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)  # the launcher shuts its embedded Ray down on the way out
        for proc in (service, prometheus):
            try:
                proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def test_prometheus_scrapes_the_buffer_the_rates_and_a_rising_lambda(live):
    assert float(live.query("cmcl_replay_size")[0]["value"][1]) > 0
    assert float(live.query("rate(cmcl_replay_inserts_total[30s])")[0]["value"][1]) > 0
    lam = json.loads(get(f"{live.api}/query?" + urllib.parse.urlencode({"query": "cmcl_curriculum_lambda[60s]"})))
    values = [float(v) for _, v in lam["data"]["result"][0]["values"]]
    assert len(values) >= 2 and values == sorted(values) and values[-1] > values[0], values


def test_prometheus_scrapes_rays_own_metrics_as_the_config_asks(live):
    assert live.wait_for('up{job="ray-head"} == 1', "Prometheus scraped Ray's metrics port")
    names = json.loads(get(f"{live.api}/label/__name__/values"))["data"]
    assert any(n.startswith("ray_") for n in names), "Ray's own metrics reached Prometheus"


def dashboard_metric_names() -> dict[str, set[str]]:
    """Metric names named by each dashboard's PromQL (Grafana JSON targets; the console template's expressions)."""
    grafana = json.loads((DEPLOY / "grafana" / "dashboards" / "cmcl.json").read_text())
    exprs = [t["expr"] for p in grafana["panels"] for t in p.get("targets", [])]
    console = re.sub(r'(template|define) "[^"]+"', "", (DEPLOY / "prometheus" / "consoles" / "cmcl.html").read_text())
    return {"grafana": {n for e in exprs for n in re.findall(r"\bcmcl_[a-z0-9_]+", e)},
            "console": set(re.findall(r"\bcmcl_[a-z0-9_]+", console))}


def exported_names(exposition: str) -> set[str]:
    """Every series name an exposition text can produce (histograms: _bucket, _count, _sum; counters: _total)."""
    names = set()
    for family in text_string_to_metric_families(exposition):
        names.add(family.name)
        if family.type == "histogram":
            names |= {family.name + s for s in ("_bucket", "_count", "_sum")}
        if family.type == "counter":
            names |= {family.name + "_total", family.name + "_created"}
    return names


def test_every_dashboard_expression_names_a_metric_the_live_endpoint_exports(live):
    exported = exported_names(get(f"http://127.0.0.1:{live.service_port}/metrics"))
    for dashboard, names in dashboard_metric_names().items():
        assert names, f"no metric found in the {dashboard} dashboard"
        assert names <= exported, f"{dashboard} names metrics the service does not export: {names - exported}"


@pytest.mark.skipif(CHROMIUM is None, reason="the Debian package chromium is not installed (make test installs it)")
def test_the_console_dashboard_renders_live_data_in_chromium(live, tmp_path):
    settle = float(os.environ.get("CMCL_SCREENSHOT_WAIT_S", 0))
    if settle:
        live.wait_for(f"vector(time()) > {time.time() + settle}", f"{settle} s more of training for the screenshot")
    span = int(time.monotonic() - live.started) + 10  # the graphs show the whole run so far
    url = f"http://127.0.0.1:{live.prometheus_port}/consoles/cmcl.html?range={span}"
    flags = [CHROMIUM, *CHROMIUM_FLAGS]
    check_console_dom(subprocess.run([*flags, "--dump-dom", url], capture_output=True, text=True, timeout=120).stdout)
    shot = tmp_path / "dashboard.png"
    subprocess.run([*flags, f"--screenshot={shot}", url], capture_output=True, timeout=120, check=True)
    assert shot.stat().st_size > 20_000 and shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert live.service.poll() is None, "the run had ended: the screenshot must show a run in progress"
    if os.environ.get("CMCL_SCREENSHOT"):
        shutil.copy(shot, os.environ["CMCL_SCREENSHOT"])

"""Static checks of deploy/ and docker-compose.yml: no Docker engine, Grafana or cluster needed.

The compose file, Prometheus config, Grafana provisioning, dashboard and KubeRay manifests must parse and agree
with each other and with services/observability/metrics.py. The two promtool tests run only where `promtool` is
installed (`apt-get install prometheus`); elsewhere they are skipped.
"""

import copy
import importlib.util
import json
import re
import shlex
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml
from jsonschema import Draft7Validator

from services.observability.metrics import ServiceMetrics

ROOT = Path(__file__).resolve().parents[1]
DEPLOY = ROOT / "deploy"
COMPOSE = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
SERVICES = COMPOSE["services"]
PROMETHEUS = yaml.safe_load((DEPLOY / "prometheus.yml").read_text())
DASHBOARD = json.loads((DEPLOY / "grafana/dashboards/cmcl.json").read_text())
DATASOURCES = yaml.safe_load((DEPLOY / "grafana/provisioning/datasources/prometheus.yml").read_text())
PROVIDERS = yaml.safe_load((DEPLOY / "grafana/provisioning/dashboards/cmcl.yml").read_text())
DATA_PANELS = [p for p in DASHBOARD["panels"] if p["type"] != "row"]
PROMTOOL = shutil.which("promtool")


def head_args() -> list[str]:
    """The launcher's arguments in the head's command (after `exec`)."""
    command = SERVICES["cmcl-head"]["command"]
    script = command[-1] if isinstance(command, list) else command
    words = shlex.split(re.sub(r"\$\{(\w+):-([^}]*)\}", r"\2", script))  # compose default values
    start = words.index("services.launch")
    return words[start + 1:]


def flag(args: list[str], name: str) -> str:
    return args[args.index(name) + 1]


def mounts(service: str) -> dict[str, str]:
    """Bind mounts of a compose service: container path -> host path (relative to the repo root)."""
    out = {}
    for volume in SERVICES[service].get("volumes", []):
        host, container = re.sub(r"\$\{(\w+):-([^}]*)\}", r"\2", volume).split(":")[:2]  # compose defaults
        if host.startswith("./"):
            out[container] = host
    return out


def test_compose_has_the_four_services_and_their_files_exist():
    assert {"cmcl-head", "cmcl-worker", "prometheus", "grafana"} <= set(SERVICES)
    build = SERVICES["cmcl-head"]["build"]
    assert (ROOT / build["context"] / build["dockerfile"]).is_file()
    assert SERVICES["cmcl-worker"]["image"] == SERVICES["cmcl-head"]["image"]
    for name, service in SERVICES.items():
        for volume in service.get("volumes", []):
            if volume.endswith(":ro"):  # inputs must exist; ./runs (output) is created by compose
                assert (ROOT / volume.split(":")[0]).exists(), f"{name} mounts missing {volume}"
    assert mounts("prometheus")["/etc/prometheus/prometheus.yml"] == "./deploy/prometheus.yml"
    assert "--config.file=/etc/prometheus/prometheus.yml" in SERVICES["prometheus"]["command"]
    assert mounts("grafana")["/etc/grafana/provisioning"] == "./deploy/grafana/provisioning"


def test_head_runs_the_launcher_with_the_agreed_flags():
    args = head_args()
    assert flag(args, "--address") == "auto"
    assert flag(args, "--metrics-host") == "0.0.0.0"
    assert 1 <= int(flag(args, "--metrics-port")) <= 65535
    assert (ROOT / flag(args, "--config")).is_file()
    script = SERVICES["cmcl-head"]["command"][-1]
    assert script.index("ray start --head") < script.index("services.launch")
    port = re.search(r"--port=(\d+)", script).group(1)
    assert f"--address=cmcl-head:{port}" in SERVICES["cmcl-worker"]["command"]


def test_published_ports_bind_loopback_only():
    for name, service in SERVICES.items():
        for port in service.get("ports", []):
            assert str(port).startswith("127.0.0.1:"), f"{name} publishes {port} beyond loopback"


def test_prometheus_scrapes_the_service_endpoint_and_ray():
    jobs = {job["job_name"]: job for job in PROMETHEUS["scrape_configs"]}
    targets = [t for group in jobs["cmcl"]["static_configs"] for t in group["targets"]]
    assert targets == [f"cmcl-head:{flag(head_args(), '--metrics-port')}"]
    ray_port = re.search(r"--metrics-export-port=(\d+)", SERVICES["cmcl-head"]["command"][-1]).group(1)
    assert f"--metrics-export-port={ray_port}" in SERVICES["cmcl-worker"]["command"]
    assert jobs["ray-head"]["static_configs"][0]["targets"] == [f"cmcl-head:{ray_port}"]
    dns = jobs["ray-workers"]["dns_sd_configs"][0]
    assert dns["names"] == ["cmcl-worker"] and dns["port"] == int(ray_port)


def test_grafana_provisioning_matches_compose_and_dashboard():
    (source,) = DATASOURCES["datasources"]
    assert source["type"] == "prometheus" and source["url"] == "http://prometheus:9090"
    assert "prometheus" in SERVICES
    (provider,) = PROVIDERS["providers"]
    assert mounts("grafana")[provider["options"]["path"]] == "./deploy/grafana/dashboards"
    home = SERVICES["grafana"]["environment"]["GF_DASHBOARDS_DEFAULT_HOME_DASHBOARD_PATH"]
    assert home == provider["options"]["path"] + "/cmcl.json"
    for panel in DATA_PANELS:
        assert panel["datasource"] == {"type": "prometheus", "uid": source["uid"]}, panel["title"]


def exprs() -> list[str]:
    return [t["expr"] for p in DATA_PANELS for t in p["targets"]]


def test_dashboard_panels_have_targets_and_a_sane_layout():
    assert DASHBOARD["uid"] and DASHBOARD["title"]
    assert len(DATA_PANELS) >= 20
    ids = [p["id"] for p in DASHBOARD["panels"]]
    assert len(ids) == len(set(ids))
    cells = set()
    for panel in DASHBOARD["panels"]:
        if panel["type"] != "row":
            assert panel["targets"] and all(t["expr"].strip() and t["refId"] for t in panel["targets"])
        g = panel["gridPos"]
        assert g["x"] + g["w"] <= 24, panel["title"]
        area = {(x, y) for x in range(g["x"], g["x"] + g["w"]) for y in range(g["y"], g["y"] + g["h"])}
        assert not cells & area, f"panel {panel['title']!r} overlaps another"
        cells |= area
    heatmaps = [p for p in DATA_PANELS if p["type"] == "heatmap"]
    assert {"cmcl_difficulty_bucket", "cmcl_priority_bucket"} <= {
        name for p in heatmaps for name in re.findall(r"cmcl_\w+", p["targets"][0]["expr"])}
    assert all(t.get("format") == "heatmap" for p in heatmaps for t in p["targets"])


def test_dashboard_uses_only_metrics_the_service_defines():
    allowed = set()
    for family in ServiceMetrics().registry.collect():
        if family.type == "histogram":
            allowed |= {family.name + s for s in ("_bucket", "_sum", "_count")}
        allowed.add(family.name + "_total" if family.type == "counter" else family.name)
    used = {name for expr in exprs() for name in re.findall(r"\bcmcl_[a-z0-9_]*[a-z0-9]\b", expr)}
    assert used and used <= allowed, sorted(used - allowed)
    bases = {re.sub(r"_(bucket|sum|count)$", "", name) for name in used}
    shown = {"cmcl_replay_size", "cmcl_replay_capacity", "cmcl_replay_inserts_total", "cmcl_replay_samples_total",
             "cmcl_replay_rejected_total", "cmcl_curriculum_lambda", "cmcl_difficulty", "cmcl_priority",
             "cmcl_teacher_score_age_updates", "cmcl_teacher_score_coverage", "cmcl_curiosity_scores_total",
             "cmcl_icm_loss", "cmcl_learner_loss", "cmcl_weight_version_lag", "cmcl_env_steps_total",
             "cmcl_coverage_rate", "cmcl_success_rate", "cmcl_episode_reward", "cmcl_win_rate",
             "cmcl_actor_restarts_total", "cmcl_updates_per_second", "cmcl_env_steps_per_second"}
    assert shown <= bases, sorted(shown - bases)


def test_kuberay_manifests():
    cluster = yaml.safe_load((DEPLOY / "kuberay/raycluster.yaml").read_text())
    assert cluster["apiVersion"] == "ray.io/v1" and cluster["kind"] == "RayCluster"
    head = cluster["spec"]["headGroupSpec"]["template"]["spec"]["containers"][0]
    assert head["resources"]["requests"]["cpu"] and head["resources"]["requests"]["memory"]
    assert 9100 in [p["containerPort"] for p in head["ports"]]
    (workers,) = cluster["spec"]["workerGroupSpecs"]
    assert workers["minReplicas"] <= workers["replicas"] <= workers["maxReplicas"]
    assert workers["template"]["spec"]["containers"][0]["resources"]["requests"]["cpu"]
    job = yaml.safe_load((DEPLOY / "kuberay/rayjob.yaml").read_text())
    assert job["kind"] == "RayJob" and job["spec"]["clusterSelector"]["ray.io/cluster"] == cluster["metadata"]["name"]
    args = shlex.split(job["spec"]["entrypoint"])
    assert flag(args, "--address") == "auto" and flag(args, "--metrics-port") == "9100"
    config = flag(args, "--config")
    assert config.startswith("/opt/cmcl/") and (ROOT / config.removeprefix("/opt/cmcl/")).is_file()


def test_dockerfile():
    text = (DEPLOY / "Dockerfile").read_text()
    assert re.search(r"^ARG BASE=python:3\.11-slim\nFROM \$\{BASE\}$", text, re.M)
    assert "WORKDIR /opt/cmcl" in text  # paths used by deploy/kuberay
    for line in re.findall(r"^COPY (.+)$", text, re.M):
        for source in line.split()[:-1]:  # deploy/wheels/ is written by deploy/wheelhouse.sh before a build
            assert (ROOT / source).exists() or source == "deploy/wheels/requirements.txt", source
    assert '> "$OUT/requirements.txt"' in (DEPLOY / "wheelhouse.sh").read_text()
    assert not re.findall(r"https?://", text.split("ARG BASE")[1]), "the build downloads nothing"
    code = "\n".join(line for line in text.splitlines() if not line.startswith("#"))
    installs = re.findall(r"pip install ([^&\n]+)", code)
    assert installs and all(i.startswith("--no-index --find-links /wheels ") for i in installs), installs
    assert text.count("--mount=type=bind,source=deploy/wheels,target=/wheels") == len(installs)
    assert "torch.__version__ == '2.13.0+cpu'" in text  # the wheelhouse's torch is the CPU build
    assert "torch==2.13.0" in (DEPLOY / "wheelhouse.sh").read_text()


def test_compose_builds_from_a_chosen_base_and_limits_every_containers_memory():
    defaults = {"cmcl-head": ("CMCL_BASE_IMAGE", "Dockerfile"),
                "prometheus": ("CMCL_DEBIAN_IMAGE", "prometheus/Dockerfile")}
    for name, (variable, dockerfile) in defaults.items():
        arg = re.search(r"^ARG BASE=(\S+)$", (DEPLOY / dockerfile).read_text(), re.M).group(1)
        assert SERVICES[name]["build"]["args"]["BASE"] == f"${{{variable}:-{arg}}}", name
        assert variable in (DEPLOY / "build_base.sh").read_text()
    for name, service in SERVICES.items():
        assert re.fullmatch(r"\d+[mg]", str(service.get("mem_limit", ""))), f"{name} has no mem_limit"
    # podman-compose 1.0.3 turns the exec form ["CMD", ...] into a shell syntax error; CMD-SHELL works in both.
    assert SERVICES["cmcl-head"]["healthcheck"]["test"][0] == "CMD-SHELL"


def test_every_ray_node_sees_the_run_directory_and_the_worker_hosts_the_rollouts():
    assert mounts("cmcl-worker")["/opt/cmcl/runs"] == mounts("cmcl-head")["/opt/cmcl/runs"]
    resource = re.search(r"--set service\.rollout_resource=(\w+)", SERVICES["cmcl-head"]["command"][-1]).group(1)
    (resources,) = [a for a in SERVICES["cmcl-worker"]["command"] if a.startswith("--resources=")]
    assert json.loads(resources.removeprefix("--resources="))[resource] >= 1


@pytest.mark.skipif(PROMTOOL is None, reason="promtool not installed (apt-get install prometheus)")
def test_promtool_accepts_the_prometheus_config():
    result = subprocess.run([PROMTOOL, "check", "config", str(DEPLOY / "prometheus.yml")],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.skipif(PROMTOOL is None, reason="promtool not installed (apt-get install prometheus)")
def test_promtool_parses_every_dashboard_expression(tmp_path):
    rules = [{"record": f"cmcl:dashboard_expr:{i}", "expr": expr.replace("$__rate_interval", "1m")}
             for i, expr in enumerate(exprs())]
    path = tmp_path / "rules.yml"
    path.write_text(yaml.safe_dump({"groups": [{"name": "dashboard", "rules": rules}]}))
    result = subprocess.run([PROMTOOL, "check", "rules", str(path)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr


def kuberay_containers() -> dict[str, dict]:
    """Every container of the KubeRay manifests that runs Ray, by role."""
    cluster = yaml.safe_load((DEPLOY / "kuberay/raycluster.yaml").read_text())
    job = yaml.safe_load((DEPLOY / "kuberay/rayjob.yaml").read_text())
    (workers,) = cluster["spec"]["workerGroupSpecs"]
    return {"head": cluster["spec"]["headGroupSpec"]["template"]["spec"]["containers"][0],
            "worker": workers["template"]["spec"]["containers"][0],
            "submitter": job["spec"]["submitterPodTemplate"]["spec"]["containers"][0]}


def test_every_ray_node_and_client_has_token_auth_on_and_one_image():
    for name in ("cmcl-head", "cmcl-worker"):
        env = SERVICES[name]["environment"]
        assert env["RAY_AUTH_MODE"] == "token" and env["RAY_AUTH_TOKEN"].startswith("${CMCL_RAY_TOKEN:?"), name
    images = {SERVICES["cmcl-head"]["image"], SERVICES["cmcl-worker"]["image"]}
    for role, container in kuberay_containers().items():
        env = {e["name"]: e for e in container["env"]}
        assert env["RAY_AUTH_MODE"]["value"] == "token", role
        assert env["RAY_AUTH_TOKEN"]["valueFrom"]["secretKeyRef"]["name"] == "cmcl-ray-token", role
        images.add(container["image"])
    assert images == {"cmcl-service:0.1.0"}, "compose and KubeRay run one image"
    cluster = yaml.safe_load((DEPLOY / "kuberay/raycluster.yaml").read_text())
    assert cluster["spec"]["headGroupSpec"]["serviceType"] == "ClusterIP", "the dashboard stays inside the cluster"


def test_every_launch_command_is_accepted_by_the_launch_parser():
    from services.launch import parse_args

    job = yaml.safe_load((DEPLOY / "kuberay/rayjob.yaml").read_text())
    commands = {"compose head": head_args(), "rayjob": shlex.split(job["spec"]["entrypoint"])[3:]}
    assert shlex.split(job["spec"]["entrypoint"])[:3] == ["python", "-m", "services.launch"]
    for name, args in commands.items():
        parsed = parse_args(args)  # argparse exits (SystemExit) on an unknown or malformed flag
        assert parsed.address == "auto", name


def test_compose_prometheus_is_the_debian_one_and_serves_the_console_dashboard():
    prometheus = SERVICES["prometheus"]
    assert (ROOT / prometheus["build"]["dockerfile"]).read_text().count("apt-get install") == 1
    assert mounts("prometheus")["/etc/prometheus/consoles"] == "./deploy/prometheus/consoles"
    assert mounts("prometheus")["/etc/prometheus/console_libraries"] == "./deploy/prometheus/console_libraries"
    assert {"--web.console.templates=/etc/prometheus/consoles",
            "--web.console.libraries=/etc/prometheus/console_libraries"} <= set(prometheus["command"])


def strict(schema: dict) -> dict:
    """A CRD schema that rejects unknown fields, as the API server does with strict field validation (kubectl's
    default since 1.27) rather than pruning them silently."""
    out = dict(schema)
    if "properties" in out:
        out["properties"] = {k: strict(v) for k, v in out["properties"].items()}
        if "additionalProperties" not in out and not out.get("x-kubernetes-preserve-unknown-fields"):
            out["additionalProperties"] = False
    for key in ("items", "additionalProperties"):
        if isinstance(out.get(key), dict):
            out[key] = strict(out[key])
    return out


def kuberay_errors(kind: str, manifest: dict) -> list[str]:
    """Where `manifest` breaks the ray.io/v1 schema of `kind` (deploy/kuberay/schema/, from KubeRay's CRDs)."""
    schema = strict(json.loads((DEPLOY / f"kuberay/schema/ray.io_v1_{kind.lower()}.json").read_text()))
    return sorted(f"{'/'.join(map(str, e.absolute_path))}: {e.message}" for e in
                  Draft7Validator(schema).iter_errors(manifest))


def test_kuberay_manifests_follow_the_kuberay_crd_schemas():
    cluster = yaml.safe_load((DEPLOY / "kuberay/raycluster.yaml").read_text())
    job = yaml.safe_load((DEPLOY / "kuberay/rayjob.yaml").read_text())
    assert kuberay_errors("RayCluster", cluster) == []
    assert kuberay_errors("RayJob", job) == []
    # The check can fail: a misspelt field, a number where the CRD wants a string and the reverse are reported.
    broken = copy.deepcopy(cluster)
    broken["spec"]["workerGroupSpecs"][0]["replica"] = 2
    broken["spec"]["workerGroupSpecs"][0]["maxReplicas"] = "4"
    broken["spec"]["headGroupSpec"]["rayStartParams"]["num-cpus"] = 2
    assert len(kuberay_errors("RayCluster", broken)) == 3, kuberay_errors("RayCluster", broken)


@pytest.mark.skipif(importlib.util.find_spec("kubernetes_validate") is None,
                    reason="kubernetes-validate not installed (pip install -e '.[dev]')")
def test_kuberay_pod_templates_are_valid_core_kubernetes_objects():
    import kubernetes_validate

    cluster = yaml.safe_load((DEPLOY / "kuberay/raycluster.yaml").read_text())
    job = yaml.safe_load((DEPLOY / "kuberay/rayjob.yaml").read_text())
    templates = {"head": cluster["spec"]["headGroupSpec"]["template"],
                 "submitter": job["spec"]["submitterPodTemplate"],
                 **{f"worker-{g['groupName']}": g["template"] for g in cluster["spec"]["workerGroupSpecs"]}}
    version = kubernetes_validate.latest_version()
    for role, template in templates.items():
        pod = {"apiVersion": "v1", "kind": "PodTemplate", "metadata": {"name": role}, "template": template}
        kubernetes_validate.validate(pod, version, strict=True)  # raises ValidationError
    broken = copy.deepcopy(templates["head"])
    broken["spec"]["containers"][0]["resources"]["request"] = {"cpu": "1"}
    with pytest.raises(kubernetes_validate.ValidationError):
        kubernetes_validate.validate({"apiVersion": "v1", "kind": "PodTemplate", "metadata": {"name": "x"},
                                      "template": broken}, version, strict=True)

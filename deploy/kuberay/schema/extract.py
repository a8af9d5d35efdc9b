"""Write the ray.io/v1 schemas of RayCluster and RayJob, taken from KubeRay's CRDs, as the JSON files beside this
script (tests/test_deploy.py validates deploy/kuberay/*.yaml against them, offline).

    python deploy/kuberay/schema/extract.py KUBERAY_CHECKOUT [TAG]

reads ray-operator/config/crd/bases/ray.io_{rayclusters,rayjobs}.yaml at TAG (default v1.7.0) with `git show`.
Each pod template (a core PodTemplateSpec, ~68 kB of schema each) is replaced by a marker object: the tests
validate those templates with the Kubernetes schemas of kubernetes-validate instead. `status` is dropped.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import yaml

HERE = Path(__file__).resolve().parent
POD_TEMPLATE = {"type": "object", "x-kubernetes-preserve-unknown-fields": True,
                "x-cmcl-pod-template-spec": "validated as a core PodTemplateSpec (kubernetes-validate)"}


def prune(node: dict, path: str = "") -> dict:
    props = node.get("properties", {})
    if {"metadata", "spec"} <= set(props) and path.lower().endswith("template"):
        return POD_TEMPLATE
    out = dict(node)
    if props:
        out["properties"] = {k: prune(v, f"{path}.{k}") for k, v in props.items() if not (path == "" and k == "status")}
    if isinstance(node.get("items"), dict):
        out["items"] = prune(node["items"], path + "[]")
    return out


def main(checkout: str, tag: str = "v1.7.0") -> None:
    commit = subprocess.run(["git", "-C", checkout, "rev-parse", f"{tag}^{{commit}}"], capture_output=True,
                            text=True, check=True).stdout.strip()
    for plural, name in (("rayclusters", "raycluster"), ("rayjobs", "rayjob")):
        path = f"ray-operator/config/crd/bases/ray.io_{plural}.yaml"
        crd = yaml.safe_load(subprocess.run(["git", "-C", checkout, "show", f"{commit}:{path}"],
                                            capture_output=True, text=True, check=True).stdout)
        (v1,) = [v for v in crd["spec"]["versions"] if v["name"] == "v1"]
        schema = prune(v1["schema"]["openAPIV3Schema"])
        schema["$comment"] = f"KubeRay {tag} ({commit}) {path}, version v1, pod templates and status pruned"
        (HERE / f"ray.io_v1_{name}.json").write_text(json.dumps(schema, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main(*sys.argv[1:])

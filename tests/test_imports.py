"""The pure core stays pure: importing cmcl (and all of its modules) pulls in neither Ray nor Prometheus, and the
replay stage never loads torch."""

import json
import subprocess
import sys


def loaded_after_importing(package: str, extra: str, roots: tuple[str, ...]) -> list[str]:
    """In a fresh interpreter, import every module of `package` and the modules in `extra`; return the loaded
    top-level packages among `roots`."""
    code = (
        f"import importlib, json, pkgutil, sys, {package}\n"
        f"for m in pkgutil.walk_packages({package}.__path__, '{package}.'):\n"
        "    importlib.import_module(m.name)\n"
        + (f"import {extra}\n" if extra else "")
        + f"print(json.dumps(sorted({{n.split('.')[0] for n in sys.modules}} & set({roots!r}))))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


def test_cmcl_does_not_import_ray_or_prometheus():
    assert loaded_after_importing("cmcl", "", ("ray", "prometheus_client", "services")) == []


def test_replay_stage_and_batched_envs_never_load_torch():
    """The replay server and continuous-action rollout workers import only these: no torch in their processes."""
    extra = ("cmcl.envs.batched, cmcl.messages, cmcl.progress, cmcl.io.records, cmcl.io.durable, "
             "cmcl.learners.policy, cmcl.system")
    assert loaded_after_importing("cmcl.replay", extra, ("torch",)) == []
    assert loaded_after_importing("cmcl.learners", "", ("torch",)) == ["torch"], "the check can see torch"

"""The pure core stays pure: importing cmcl (and all of its modules) pulls in neither Ray nor Prometheus."""

import subprocess
import sys


def test_cmcl_does_not_import_ray_or_prometheus():
    code = (
        "import importlib, pkgutil, sys, cmcl\n"
        "for m in pkgutil.walk_packages(cmcl.__path__, 'cmcl.'):\n"
        "    importlib.import_module(m.name)\n"
        "bad = sorted(n for n in sys.modules if n.split('.')[0] in ('ray', 'prometheus_client', 'services'))\n"
        "print(bad)\n"
        "sys.exit(1 if bad else 0)\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr


def test_replay_stage_and_batched_envs_never_load_torch():
    """The replay server and continuous-action rollout workers import only these: no torch in their processes."""
    code = (
        "import importlib, pkgutil, sys, cmcl.replay\n"
        "for m in pkgutil.walk_packages(cmcl.replay.__path__, 'cmcl.replay.'):\n"
        "    importlib.import_module(m.name)\n"
        "import cmcl.envs.batched, cmcl.messages, cmcl.progress, cmcl.io.codec, cmcl.learners.policy, cmcl.system\n"
        "print(sorted(n for n in sys.modules if n.split('.')[0] == 'torch')[:3])\n"
        "sys.exit(1 if 'torch' in sys.modules else 0)\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr

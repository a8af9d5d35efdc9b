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
    extra = ("cmcl.envs.batched, cmcl.replay.messages, cmcl.scorers.scoring, cmcl.progress.rows, cmcl.io.records, "
             "cmcl.io.durable, cmcl.rollout.policy, cmcl.system")
    assert loaded_after_importing("cmcl.replay", extra, ("torch",)) == []
    assert loaded_after_importing("cmcl.learners", "", ("torch",)) == ["torch"], "the check can see torch"


def test_the_training_commands_load_no_torch_before_the_run_directory_is_taken():
    """`python -m cmcl train` (either runner: both run services.launch) and `python -m services.launch` import their
    runner, then take the run directory's lock: a second writer on a run in use is refused without first loading
    torch or Ray (~4 s of a 2-core machine's time; the training itself imports them once the lock is held)."""
    code = ("import json, sys, cmcl.__main__, services.launch\n"
            "print(json.dumps(sorted({n.split('.')[0] for n in sys.modules} & {'torch', 'ray'})))\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout) == []


def test_a_command_ends_with_its_exit_status_its_output_flushed_and_no_teardown():
    """cmcl.run.stopping.exit_without_teardown, the last step of every training and evaluation command."""
    code = ("import atexit, sys\nfrom cmcl.run.stopping import exit_without_teardown\n"
            "atexit.register(lambda: print('teardown ran'))\n"
            "print('the last line', end='')\nprint('and its error', end='', file=sys.stderr)\n"
            "exit_without_teardown(130)\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert (result.returncode, result.stdout, result.stderr) == (130, "the last line", "and its error")

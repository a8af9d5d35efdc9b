"""The help and the docs say what the program does, as a new user meets it (subprocesses): every verb in `--help`'s
usage line and in docs/USAGE.md; a standalone `evaluate` prints the random-policy baseline as `train` does and
writes nothing into a run directory another process holds; the GIF's failure reason is never empty; rendering never
leaves SDL without a runtime folder; a near-miss config key is answered with the likely key and its file named."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest

import cmcl.run.evaluate as evaluate_module
from cmcl.__main__ import build_parser
from cmcl.config import load_config
from cmcl.run.runlock import RunLock
from tests.evaluation_output import evaluation_json

ROOT = Path(__file__).resolve().parents[1]
REACH = ["--set", "env.factory=cmcl.envs.examples.reach:parallel_env", "--set", "env.success_key=reached"]
TINY = [arg for text in ("env.num_envs=2", "maddpg.batch_size=16", "maddpg.warmup=32", "maddpg.hidden=16",
                         "replay.capacity=600", "run.episodes=8")
        for arg in ("--set", text)]


def cmcl(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cmcl", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)


def verbs() -> list[str]:
    return list(build_parser()._subparsers._group_actions[0].choices)


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory) -> Path:
    """A tiny inline run of the from-scratch example, trained to its end without an evaluation."""
    run_dir = tmp_path_factory.mktemp("eval") / "run"
    done = cmcl("train", "--runner", "inline", *REACH, *TINY, "--set", f"run.dir={run_dir}", "--no-eval")
    assert done.returncode == 0, done.stderr
    return run_dir


def test_every_verb_is_in_the_help_usage_and_in_usage_md():
    usage = cmcl("--help").stdout.split("\n\n")[0]  # the usage lines (argparse wraps them past 80 columns)
    doc = (ROOT / "docs" / "USAGE.md").read_text()
    assert len(verbs()) == 7
    for verb in verbs():
        assert verb in usage, usage
        assert f"python -m cmcl {verb}" in doc, verb
    assert "seven verbs" in doc


def test_a_standalone_evaluate_prints_the_random_baseline(trained_run):
    done = cmcl("evaluate", str(trained_run), "--episodes", "5", "--no-gif")
    assert done.returncode == 0, done.stderr
    result = evaluation_json(done.stdout)
    assert set(result["random_policy"]["reward"]) == {"agent"}
    line = next(line for line in done.stderr.splitlines() if line.startswith("held-out evaluation"))
    assert "| random policy: success " in line and "return[agent]" in line


def test_evaluate_writes_nothing_into_a_run_another_process_holds(trained_run):
    for name in ("learning_curve.png", "eval.gif"):
        (trained_run / name).unlink(missing_ok=True)
    before = sorted(p.name for p in trained_run.iterdir())
    with RunLock.acquire(trained_run, "a training run"):
        done = cmcl("evaluate", str(trained_run), "--episodes", "3")
    assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in trained_run.iterdir()) == before
    note = next(line for line in done.stderr.splitlines() if "writes nothing there" in line)
    elsewhere = Path(note.rsplit(" go to ", 1)[1])
    assert (elsewhere / "learning_curve.png").is_file()
    assert f"learning curve: {elsewhere / 'learning_curve.png'}" in done.stdout


def test_a_gif_failure_without_a_message_names_the_error(monkeypatch):
    def no_render(*args, **kwargs):
        raise NotImplementedError()

    monkeypatch.setattr(evaluate_module, "gif_bytes", no_render)
    line = evaluate_module.gif_line(load_config(None, []), None, "unused.gif")
    assert line == "gif: none, the environment could not render here (NotImplementedError, raised without a message)"


def test_rendering_gets_a_valid_sdl_runtime_folder(monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path / "missing"))
    evaluate_module.headless_sdl()
    runtime = Path(os.environ["XDG_RUNTIME_DIR"])
    assert runtime.is_dir() and stat.S_IMODE(runtime.stat().st_mode) == 0o700
    kept = tmp_path / "own"
    kept.mkdir(mode=0o700)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(kept))
    evaluate_module.headless_sdl()
    assert os.environ["XDG_RUNTIME_DIR"] == str(kept)


def test_a_near_miss_key_names_the_likely_key_and_the_file(tmp_path):
    config = tmp_path / "mine.toml"
    config.write_text("[run]\nepisode = 40\n")
    done = cmcl("train", "--runner", "inline", "--config", str(config), "--set", f"run.dir={tmp_path / 'run'}")
    assert done.returncode == 2 and len(done.stderr.splitlines()) == 1, done.stderr
    assert "unknown key run.episode; did you mean run.episodes?" in done.stderr and str(config) in done.stderr
    by_flag = cmcl("train", "--runner", "inline", "--set", "maddpg.hiden=8", "--set", f"run.dir={tmp_path / 'run'}")
    assert "did you mean maddpg.hidden?" in by_flag.stderr and "(in " not in by_flag.stderr

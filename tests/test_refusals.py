"""Bad input meets one line, not a traceback (issue 37, "refusals that are tracebacks"): each case runs the command as
a user runs it (a subprocess) and expects exit 2, exactly one line on stderr naming the key, flag or file and its
value, and nothing left in the run directory that would block the corrected command.

- the user's environment (env.factory) failing in its constructor, reset or first step; its teams not those of the
  config; a user's env with team names of its own and no [teams] table (trains, each team at the default settings);
- sizes that do not fit in memory (env.num_envs, replay.capacity, evaluate --episodes), checked before allocating;
- config files that are not TOML text (binary, a directory).

The service runner runs the same checks in the launcher before Ray starts (`test_the_service_refuses_*`).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TEAMS_ENV = "env.factory=tests.team_env:parallel_env"
QUICK = ["--set", "run.episodes=2", "--quiet", "--no-eval"]


def run_cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cmcl", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=timeout)


def assert_one_line_refusal(done: subprocess.CompletedProcess, *named: str) -> None:
    """Exit 2 and one stderr line starting 'error: ' that contains every string of `named`."""
    lines = done.stderr.splitlines()
    assert done.returncode == 2 and len(lines) == 1 and lines[0].startswith("error: "), \
        f"exit {done.returncode}, stderr:\n{done.stderr}"
    for text in named:
        assert text in lines[0], lines[0]


@pytest.mark.parametrize(("fail_in", "named"), [
    ("init", "raised KeyError: 'map_file' (at team_env.py line"),
    ("reset", "raised RuntimeError: no map loaded (at team_env.py line"),
    ("step", "its first step (every agent's middle action) raised ZeroDivisionError: division by zero"),
    ("bogus", "raised TypeError: Teams.__init__() got an unexpected keyword argument 'bogus'"),
])
def test_an_error_of_the_users_environment_is_one_line_naming_env_factory(fail_in, named, tmp_path):
    kwargs = "env.factory_kwargs={bogus=1}" if fail_in == "bogus" else f'env.factory_kwargs={{fail_in="{fail_in}"}}'
    done = run_cli("train", "--runner", "inline", "--set", TEAMS_ENV, "--set", kwargs, "--set",
                   f"run.dir={tmp_path / 'run'}", *QUICK)
    assert_one_line_refusal(done, "env.factory 'tests.team_env:parallel_env'", named)
    assert not (tmp_path / "run").exists()


def test_a_users_env_with_its_own_team_names_trains_without_a_teams_table(tmp_path):
    """Only env.factory set: every team the env's agent ids form (scout, walker) gets the default team settings, the
    run says so in one line, and the run's config.toml names those teams (so resume and evaluate read them)."""
    run_dir = tmp_path / "run"
    done = run_cli("train", "--runner", "inline", "--set", TEAMS_ENV, "--set", f"run.dir={run_dir}",
                   "--set", "env.num_envs=2", *QUICK)
    assert done.returncode == 0, done.stdout + done.stderr
    notes = [line for line in done.stdout.splitlines() if line.startswith("teams:")]
    assert notes == ["teams: no [teams] table, so each team of env.factory 'tests.team_env:parallel_env' gets the "
                     "default team settings (algorithm 'cmcl'): scout: scout_0, scout_1; walker: walker_0"]
    config = (run_dir / "config.toml").read_text()
    assert "[teams.scout]" in config and "[teams.walker]" in config and "[teams.agent]" not in config


def test_teams_that_are_not_the_environments_are_one_line(tmp_path):
    """A config file's own [teams.agent] table with an env whose agents form other teams: refused, naming both."""
    done = run_cli("train", "--runner", "inline", "--config", "configs/spread_cmcl.toml", "--set", TEAMS_ENV,
                   "--set", f"run.dir={tmp_path / 'run'}", *QUICK)
    assert_one_line_refusal(done, "teams: the config names ['agent']", "'scout': ['scout_0', 'scout_1']")
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(("setting", "named"), [
    ("env.num_envs=100000000", "env.num_envs = 100000000 needs about "),
    ("replay.capacity=1000000000000", "replay.capacity = 1000000000000 needs about "),
])
def test_sizes_that_do_not_fit_in_memory_are_refused_before_allocating(setting, named, tmp_path):
    done = run_cli("train", "--runner", "inline", "--set", setting, "--set", f"run.dir={tmp_path / 'run'}", *QUICK)
    assert_one_line_refusal(done, named, "this machine has available")
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("kind", ["binary", "directory"])
def test_a_config_file_that_is_not_toml_text_is_named(kind, tmp_path):
    path = tmp_path / "config.toml"
    if kind == "binary":
        path.write_bytes(bytes([0x8F, 0x00, 0xFF, 0xDD]) * 64)
    else:
        path.mkdir()
    done = run_cli("train", "--runner", "inline", "--config", str(path), *QUICK)
    assert_one_line_refusal(done, f"config file {str(path)!r}",
                            "not UTF-8 text (byte 0x8f at offset 0)" if kind == "binary" else "is a directory")

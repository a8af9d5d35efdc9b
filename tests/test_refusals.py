"""Bad input meets one line, not a traceback ("refusals that are tracebacks"): each case runs the command as
a user runs it (a subprocess) and expects exit 2, exactly one line on stderr naming the key, flag or file and its
value, and nothing left in the run directory that would block the corrected command.

- the user's environment (env.factory) failing in its constructor, reset or first step; its teams not those of the
  config; a user's env with team names of its own and no [teams] table (trains, each team at the default settings);
- sizes that do not fit in memory (env.num_envs, replay.capacity, evaluate --episodes), checked before allocating;
- config files that are not TOML text (binary, a directory).

The service runner runs the same checks in the launcher before Ray starts (`test_the_service_refuses_*`).
"""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TEAMS_ENV = "env.factory=tests.team_env:parallel_env"
QUICK = ["--set", "run.episodes=2", "--quiet", "--no-eval"]


def any_port(runner: str) -> list[str]:
    """The service's metrics on a free port (a `make run` beside the suite holds the default 9100, which the launcher
    then refuses first); the inline runner refuses metrics flags."""
    return ["--metrics-port", "0"] if runner == "service" else []


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
@pytest.mark.parametrize("runner", ["inline", "service"])
def test_an_error_of_the_users_environment_is_one_line_naming_env_factory(runner, fail_in, named, tmp_path):
    """On the service the launcher builds the env before Ray starts: one line, not one traceback per actor."""
    kwargs = "env.factory_kwargs={bogus=1}" if fail_in == "bogus" else f'env.factory_kwargs={{fail_in="{fail_in}"}}'
    done = run_cli("train", "--runner", runner, *any_port(runner), "--set", TEAMS_ENV, "--set", kwargs, "--set",
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
                     "default team settings (algorithm 'maddpg'): scout: scout_0, scout_1; walker: walker_0"]
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
@pytest.mark.parametrize("runner", ["inline", "service"])
def test_sizes_that_do_not_fit_in_memory_are_refused_before_allocating(runner, setting, named, tmp_path):
    done = run_cli("train", "--runner", runner, *any_port(runner), "--set", setting, "--set",
                   f"run.dir={tmp_path / 'run'}", *QUICK)
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



@pytest.mark.parametrize("runner", ["inline", "service"])
@pytest.mark.parametrize("where", ["a file", "under a file"])
def test_a_run_dir_that_cannot_be_a_folder_is_named_and_the_file_kept(runner, where, tmp_path):
    """Before: "error: [Errno 17] File exists: '...'" with no key named (found by hand, 2026-12-06)."""
    taken = tmp_path / "notes.txt"
    taken.write_text("a user's file\n")
    run_dir = taken if where == "a file" else taken / "run"
    done = run_cli("train", "--runner", runner, "--set", f"run.dir={run_dir}", *QUICK, *any_port(runner))
    assert_one_line_refusal(done, f"run.dir = {str(run_dir)!r} cannot hold a run: "
                            + ("it is a file" if where == "a file" else "a folder on its path is a file"))
    assert taken.read_text() == "a user's file\n"


@pytest.mark.parametrize("runner", ["inline", "service"])
def test_a_folder_of_the_users_that_holds_no_run_is_refused_and_left_as_it_was(runner, tmp_path):
    """Before (found by hand 2026-12-06): `train --overwrite` into a folder of the user's that held no run deleted its
    checkpoints/ and metrics.jsonl, then trained there."""
    folder = tmp_path / "project"
    (folder / "checkpoints").mkdir(parents=True)
    (folder / "checkpoints" / "model.bin").write_bytes(b"the user's weights")
    (folder / "metrics.jsonl").write_text("{}\n")
    before = {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()}
    done = run_cli("train", "--runner", runner, "--set", f"run.dir={folder}", "--overwrite", *QUICK, *any_port(runner))
    assert_one_line_refusal(done, f"run.dir {str(folder)!r} holds files that are not a run's (checkpoints, "
                                  "metrics.jsonl); nothing there is touched")
    assert {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()} == before  # no lock file left either

def test_a_start_that_fails_before_its_first_episode_leaves_nothing(tmp_path, capsys):
    """Whatever ends a new run before its first episode (an error exit, an exception), its config.toml, run.lock,
    empty checkpoints/ and the directory the command made are removed; a directory that existed is kept."""
    from cmcl.run.flags import RunRequest, train_in_run

    def fails(config, run_dir, lock):
        assert run_dir.config_path.is_file() and run_dir.checkpoints.is_dir()
        (run_dir.checkpoints / "service").mkdir()
        return 2

    def raises(config, run_dir, lock):
        raise RuntimeError("an actor died")

    run_dir = tmp_path / "new" / "run"
    assert train_in_run(RunRequest(runner="inline", overrides=(f"run.dir={run_dir}",)), fails) == 2
    assert not run_dir.exists()
    with pytest.raises(RuntimeError, match="an actor died"):
        train_in_run(RunRequest(runner="inline", overrides=(f"run.dir={run_dir}",)), raises)
    assert not run_dir.exists()
    kept = tmp_path / "kept"
    kept.mkdir()
    assert train_in_run(RunRequest(runner="inline", overrides=(f"run.dir={kept}",)), fails) == 2
    assert kept.is_dir() and list(kept.iterdir()) == []


def test_what_a_failed_start_left_does_not_block_the_retry_and_resume_names_the_command_that_works(tmp_path):
    """The leftovers of a failed start (of the code before: config.toml, run.lock, an empty checkpoints/) are not a
    run: `train` takes the directory (before: "already holds a run; pass --resume DIR", a flag train does not
    have), and `resume` prints the train command (before: "cannot tell which runner wrote")."""
    from cmcl.config import dump_toml, load_config

    run_dir = tmp_path / "run"
    (run_dir / "checkpoints").mkdir(parents=True)
    (run_dir / "run.lock").write_text("{}")
    (run_dir / "config.toml").write_text(dump_toml(load_config(None, [f"run.dir={run_dir}"])))
    resumed = run_cli("resume", str(run_dir))
    assert_one_line_refusal(resumed, f"cannot tell which runner wrote {str(run_dir)!r}: it never trained",
                            f"-m cmcl train --config {run_dir / 'config.toml'}")
    done = run_cli("train", "--runner", "inline", "--set", f"run.dir={run_dir}", "--set", "env.num_envs=2", *QUICK)
    assert done.returncode == 0, done.stdout + done.stderr
    assert (run_dir / "summary.json").is_file()
    again = run_cli("train", "--runner", "inline", "--set", f"run.dir={run_dir}", *QUICK)
    assert_one_line_refusal(again, f"run.dir {str(run_dir)!r} already holds a run: continue it with ",
                            f"-m cmcl resume {run_dir}, start over with --overwrite")


# out of the default run (its 10-minute budget): waits out the probe's timeout
@pytest.mark.extended
def test_a_cluster_that_does_not_answer_is_one_line_within_seconds(tmp_path):
    """--address of no cluster (a closed port): refused within the probe's timeout (Ray's own join retried for
    150 s and more, with only its warnings), before the run directory is made."""
    import socket

    with socket.socket() as probe:  # a port nothing listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    done = run_cli("train", "--address", f"127.0.0.1:{port}", "--set", f"run.dir={tmp_path / 'run'}", *QUICK,
                   timeout=60)
    assert_one_line_refusal(done, f"cannot join the Ray cluster at --address 127.0.0.1:{port}: no Ray cluster "
                                  "answered at ", "s (Timed out while waiting for GCS")
    assert not (tmp_path / "run").exists()


def trained_run(tiny_config, path: Path, episodes: int = 4, algorithm: str = "maddpg"):
    """A finished tiny inline run in `path`, trained in this process, every role checkpointed at its end."""
    from tests.in_process import trained_inline_run

    return trained_inline_run(tiny_config(algorithm, dir=str(path), episodes=episodes))


def test_evaluate_refuses_episodes_that_do_not_fit_and_a_file_that_is_not_a_policy(tmp_path, tiny_config):
    """--episodes 10⁸ (one world each: 26.8 GiB asked of numpy, a traceback) and --checkpoint at a verified file
    that is no policy (the run's teacher checkpoint: a KeyError, a traceback) are one line each."""
    run_dir = trained_run(tiny_config, tmp_path / "run", algorithm="cmcl")
    done = run_cli("evaluate", str(run_dir.path), "--episodes", "100000000", "--no-gif")
    assert_one_line_refusal(done, "--episodes = 100000000 needs about ", "this machine has available")
    (teacher,) = run_dir.service_dir.glob("teacher_*-000001.pt")
    done = run_cli("evaluate", str(run_dir.path), "--checkpoint", str(teacher), "--episodes", "4", "--no-gif")
    assert_one_line_refusal(done, f"--checkpoint {teacher} is not a policy checkpoint of this run (KeyError: ")


def test_a_metrics_file_that_is_a_directory_is_named_by_every_command(tmp_path, tiny_config):
    run_dir = trained_run(tiny_config, tmp_path / "run")
    run_dir.metrics_path.unlink()
    run_dir.metrics_path.mkdir()
    named = f"{run_dir.metrics_path} is a directory, not the run's metrics file; move it away"
    assert_one_line_refusal(run_cli("evaluate", str(run_dir.path), "--episodes", "4", "--no-gif"), named)
    assert_one_line_refusal(run_cli("resume", str(run_dir.path), "--more-episodes", "2", "--quiet"), named)
    assert_one_line_refusal(run_cli("train", "--runner", "inline", "--config", str(run_dir.config_path),
                                    "--overwrite", *QUICK), named)
    assert run_dir.metrics_path.is_dir() and (run_dir.service_dir / "learner-000001.pt").is_file()


def test_evaluate_of_a_read_only_run_directory_only_reads_it(tmp_path, tiny_config):
    """The run directory mounted read-only (a private mount namespace): the evaluation is printed, and the GIF and
    the learning curve are said not written (before: an OSError traceback from writing learning_curve.png)."""
    import shutil

    run_dir = trained_run(tiny_config, tmp_path / "run")
    if shutil.which("unshare") is None or subprocess.run(["unshare", "-m", "true"]).returncode != 0:
        pytest.skip("no private mount namespace here (unshare -m)")
    path = shlex.quote(str(run_dir.path))
    done = subprocess.run(["unshare", "-m", "sh", "-c", f"mount --bind {path} {path} && mount -o remount,bind,ro "
                           f"{path} {path} && exec {shlex.quote(sys.executable)} -m cmcl evaluate {path} --episodes 4"],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stdout + done.stderr
    assert f"gif: not written, {run_dir.path} is read-only (pass --gif PATH to write it elsewhere)" in done.stdout
    assert f"learning curve: not written, {run_dir.path} is read-only" in done.stdout
    assert not (run_dir.path / "learning_curve.png").exists() and not (run_dir.path / "eval.gif").exists()


def test_evaluate_says_when_it_falls_back_to_an_older_checkpoint(tmp_path, tiny_config):
    """The newest checkpoint bit-flipped: evaluate takes the one before, and says so, naming the refused file."""
    from cmcl.__main__ import main

    run_dir = trained_run(tiny_config, tmp_path / "run")  # the learner's checkpoint at 4 episodes, then at 8
    assert main(["resume", str(run_dir.path), "--more-episodes", "4", "--quiet", "--no-eval"]) == 0
    newest = run_dir.service_dir / "learner-000002.pt"
    data = bytearray(newest.read_bytes())
    data[100] ^= 0x01
    newest.write_bytes(bytes(data))
    done = run_cli("evaluate", str(run_dir.path), "--episodes", "4", "--no-gif")
    assert done.returncode == 0, done.stderr
    notes = [line for line in done.stderr.splitlines() if line.startswith("note: ")]
    assert notes == [f"note: evaluating {run_dir.service_dir / 'learner-000001.pt'}, an older checkpoint: refused "
                     f"{newest}: SHA-256 differs from its checksum (corrupted)"], done.stderr


def test_a_busy_metrics_port_is_named_before_ray_starts_and_the_inline_runner_refuses_metrics_flags(tmp_path):
    """The service's metrics port in use: one line naming service.metrics_port and the port, before Ray and before
    the run directory (before: "[Errno 98] Address already in use" after Ray's start, the run directory left). The
    inline runner serves no metrics: --metrics-port / --metrics-host are refused (before: accepted and ignored)."""
    import socket

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        done = run_cli("train", "--metrics-port", str(port), "--set", f"run.dir={tmp_path / 'run'}", *QUICK)
    assert_one_line_refusal(done, f"service.metrics_port = {port} is in use on 127.0.0.1: pass --metrics-port 0")
    assert not (tmp_path / "run").exists()
    for flag, value in (("--metrics-port", "9100"), ("--metrics-host", "0.0.0.0")):
        done = run_cli("train", "--runner", "inline", flag, value, "--set", f"run.dir={tmp_path / 'run'}", *QUICK)
        assert_one_line_refusal(done, f"{flag} {value} is a flag of the service runner",
                                "without Ray or a metrics endpoint")
    assert not (tmp_path / "run").exists()


# the service case is extended (out of the default run's budget); the inline case stays in the default run
@pytest.mark.parametrize("runner", ["inline", pytest.param("service", marks=pytest.mark.extended)])
def test_training_that_diverges_ends_with_one_line_and_a_summary(runner, tmp_path):
    """maddpg.critic_lr = 1e30: the weights go NaN at the first updates; the run ends with exit 2, one line naming
    the learning rates, and summary.json ended = "diverged". Before: inline, "actions must be finite" from the env,
    a traceback, no summary; the service stalled at 0 env steps/s, its learner reports refused, until stopped."""
    import json

    run_dir = tmp_path / "run"
    service = ["--set", "teachers.num_folds=3", "--set", "service.updates_per_call=8", "--metrics-port", "0"]
    done = run_cli("train", "--runner", runner, "--set", "maddpg.critic_lr=1e30", "--set", f"run.dir={run_dir}",
                   "--set", "run.episodes=200", "--set", "maddpg.warmup=64", "--set", "maddpg.batch_size=16",
                   "--set", "env.num_envs=2", "--set", "replay.capacity=600", "--set", "maddpg.hidden=32",
                   *(service if runner == "service" else []), "--quiet", "--no-eval", timeout=240)
    stderr = [line for line in done.stderr.splitlines() if not re.match(r"\d{4}-\d\d-\d\d \S+\s+(WARNING|INFO) ", line)]
    assert done.returncode == 2 and len(stderr) == 1, done.stderr  # Ray's own start lines aside
    assert stderr[0].startswith("error: training diverged at episode ") and "maddpg.critic_lr = 1e+30" in stderr[0]
    assert json.loads((run_dir / "summary.json").read_text())["ended"] == "diverged"

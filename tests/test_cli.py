"""One entry point, `python -m cmcl train | resume | evaluate`, its aliases and its refusals.

- The training commands (`python -m cmcl train|resume`, its alias `python -m services.launch`) have the same flags
  and turn the same arguments into the same `RunRequest`; the two evaluate commands likewise.
- Each verb runs as a user runs it, a subprocess, on the inline runner with the tiny config; `resume` finds the
  runner from the run directory itself, and either runner resumes a run of either (one checkpoint format).
- Bad input (an unknown verb or runner, a folder that is not a run, a service flag for the inline runner, a run of
  the inline runner's own old checkpoint format, a config key of an older layout, a run stored with one) exits with
  2 and a message naming the value, and leaves what is stored untouched.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from cmcl.__main__ import build_parser, main
from cmcl.io.resume_hint import python_command
from cmcl.io.verified import VerifiedFile
from cmcl.run.evaluate import build_parser as evaluate_alias_parser
from cmcl.run.flags import LAST_OWN_INLINE_FORMAT, RunRequest, open_run, request_from
from cmcl.run.rundir import RunDirectory
from cmcl.run.runlock import LOCK_NAME
from cmcl.run.status import runner_of
from services.launch import build_parser as launch_alias_parser
from tests.evaluation_output import evaluation_json
from tests.in_process import trained_inline_run

ROOT = Path(__file__).resolve().parents[1]


def verbs() -> dict[str, argparse.ArgumentParser]:
    """The sub-command parsers of `python -m cmcl`, by verb."""
    return next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices


def options(parser: argparse.ArgumentParser) -> set[str]:
    return {s for action in parser._actions for s in action.option_strings if s not in ("-h", "--help")}


def one_value_each(parser: argparse.ArgumentParser, skip: set[str]) -> list[str]:
    """An argument list giving every optional flag of `parser` (but `skip`) a value of its type."""
    argv: list[str] = []
    for action in parser._actions:
        flag = max(action.option_strings, key=len, default=None)
        if flag is None or flag in skip or flag == "--help":
            continue
        if action.nargs == 0:
            argv.append(flag)
        elif flag == "--set":
            argv += [flag, "run.episodes=3", flag, "run.seed=5"]
        else:
            argv += [flag, "7" if action.type is int else f"value-of{flag}"]
    return argv


def run_cli(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cmcl", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=timeout)


def trained_run(tiny_config, path: Path, episodes: int = 4, algorithm: str = "maddpg", **sections) -> RunDirectory:
    """A finished tiny inline run in `path`, trained in this process, every role checkpointed at its end."""
    return trained_inline_run(tiny_config(algorithm, dir=str(path), episodes=episodes, sections=sections))


def same_tensors(a, b) -> bool:
    """Whether two nested state dicts hold the same keys and equal tensors (and equal other values)."""
    import torch

    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(same_tensors(a[k], b[k]) for k in a)
    if isinstance(a, torch.Tensor):
        return isinstance(b, torch.Tensor) and torch.equal(a, b)
    return a == b


def learner_generations(run_dir: RunDirectory) -> list[int]:
    """The generations of the learner's checkpoint (the run's policy) on disk, newest first."""
    return VerifiedFile(run_dir.service_dir / "learner.pt").generations()


def stored_files(path: Path) -> dict[Path, bytes]:
    """Every file under `path` and its bytes, but run.lock (which names the last process that asked for the lock)."""
    return {p: p.read_bytes() for p in path.rglob("*") if p.is_file() and p.name != LOCK_NAME}


def test_the_training_commands_have_one_set_of_flags_and_make_the_same_request():
    train, resume = verbs()["train"], verbs()["resume"]
    aliases = {"services.launch": launch_alias_parser()}
    for name, alias in aliases.items():
        assert options(alias) == options(train) - {"--runner"} | {"--resume", "--more-episodes"}, name
    assert options(resume) == options(train) - {"--config", "--overwrite"} | {"--more-episodes"}

    argv = one_value_each(train, skip={"--runner", "--more-episodes"})
    expected = request_from(train.parse_args(["--runner", "service", *argv]), "service")
    assert expected.overrides == ("run.episodes=3", "run.seed=5") and expected.address == "value-of--address"
    for name, alias in aliases.items():
        assert request_from(alias.parse_args(argv), "service") == expected, name

    argv = one_value_each(resume, skip={"--runner"})
    expected = request_from(resume.parse_args(["runs/x", *argv]), "service", resume_dir="runs/x")
    assert expected.resume_dir == "runs/x" and expected.num_cpus == 7 and expected.more_episodes == 7
    for name, alias in aliases.items():
        assert request_from(alias.parse_args(["--resume", "runs/x", *argv]), "service") == expected, name


def test_the_evaluate_commands_have_one_set_of_flags():
    evaluate, alias = verbs()["evaluate"], evaluate_alias_parser()
    assert options(evaluate) == options(alias)
    argv = ["runs/x", *one_value_each(alias, skip=set())]
    assert vars(evaluate.parse_args(argv)) == vars(alias.parse_args(argv))


def test_train_runs_the_inline_runner_to_its_budget(tmp_path, tiny_config_file):
    run_dir = tmp_path / "run"
    config = tiny_config_file("cmcl", dir=str(run_dir), episodes=8)
    trained = run_cli("train", "--runner", "inline", "--config", str(config))
    assert trained.returncode == 0, trained.stdout + trained.stderr
    assert "ep 8/8" in trained.stdout and f"run directory: {run_dir}" in trained.stdout
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["runner"] == "inline" and summary["ended"] == "budget" and summary["episodes"] == 8
    assert (run_dir / "learning_curve.png").stat().st_size > 0
    # the end of the run as the service's (cmcl.run.report): the done line, the held-out evaluation, the GIF
    assert f"done: 8 episodes, {summary['env_steps']} env steps, {summary['updates']} updates in " in trained.stdout
    assert "held-out evaluation (200 new worlds, no exploration noise): coverage " in trained.stdout
    assert f"gif: {run_dir / 'trained.gif'}" in trained.stdout and (run_dir / "trained.gif").stat().st_size > 0
    newest = RunDirectory.open(run_dir).newest_policy()
    assert newest.path == run_dir / "checkpoints" / "service" / "learner-000001.pt"
    holder = json.loads((run_dir / LOCK_NAME).read_text())
    assert holder["command"].startswith("python -m cmcl train --runner inline"), holder


def test_resume_finds_the_runner_that_wrote_the_run_and_goes_on(tmp_path, tiny_config):
    run_dir = trained_run(tiny_config, tmp_path / "run")
    assert runner_of(run_dir) == "inline"
    resumed = run_cli("resume", str(run_dir.path), "--set", "run.episodes=8", "--quiet", "--no-eval")
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    assert f"resuming {run_dir.path} from checkpoints/service/learner-000001.pt (policy version " in resumed.stdout
    assert "Ray" not in resumed.stdout + resumed.stderr and not (run_dir.path / "ray_shutdown.log").exists()
    assert [r["episodes"] for r in run_dir.rows("episode")] == list(range(1, 9))
    assert run_dir.summary()["runner"] == "inline" and run_dir.summary()["episodes"] == 8
    assert not (run_dir.path / "learning_curve.png").exists(), "--no-eval: no learning curve"


def test_more_episodes_of_a_rule_that_does_not_read_lambda_say_no_lambda_stride(tmp_path, tiny_config):
    run_dir = trained_run(tiny_config, tmp_path / "run")  # MADDPG: uniform replay, no λ
    more = run_cli("resume", str(run_dir.path), "--more-episodes", "4", "--no-eval")
    assert more.returncode == 0, more.stdout + more.stderr
    assert "run.episodes: 8 (4 more than the 4 done)\n" in more.stdout and "λ" not in more.stdout, more.stdout


def test_a_finished_run_is_said_so_on_resume_and_more_episodes_train_it_further(tmp_path, tiny_config, capsys):
    """A run that ended at its budget, resumed as it is, only evaluates and says how to train further; with
    --more-episodes N it trains N episodes past those it did, its derived λ stride unchanged (said only where a rule
    reads λ); a multiplicative λ schedule, whose growth follows run.episodes, is refused naming it, the run
    untouched."""
    # 3 teacher folds: each holds an episode of the 4 (a fold without one gets no fit steps yet)
    run_dir = trained_run(tiny_config, tmp_path / "run", algorithm="acl", teachers={"num_folds": 3})
    policy, updates = run_dir.newest_policy().state, run_dir.summary()["updates"]
    again = run_cli("resume", str(run_dir.path), "--quiet", "--no-eval")
    assert again.returncode == 0, again.stdout + again.stderr
    assert "has done all its run.episodes = 4: nothing to train" in again.stderr
    assert f"-m cmcl resume {run_dir.path} --more-episodes N" in again.stderr
    assert [r["episodes"] for r in run_dir.rows("episode")] == [1, 2, 3, 4]
    assert run_dir.summary()["updates"] == updates and same_tensors(run_dir.newest_policy().state, policy)

    stride = run_dir.config().curriculum_stride()
    more = run_cli("resume", str(run_dir.path), "--more-episodes", "4", "--no-eval")
    assert more.returncode == 0, more.stdout + more.stderr
    assert f"run.episodes: 8 (4 more than the 4 done); λ stride {stride:.4g} per env step" in more.stdout
    assert [r["episodes"] for r in run_dir.rows("episode")] == list(range(1, 9))
    assert run_dir.summary()["episodes"] == 8

    before = stored_files(run_dir.path)
    assert main(["resume", str(run_dir.path), "--more-episodes", "4", "--set", "curriculum.kind=multiplicative",
                 "--quiet", "--no-eval"]) == 2
    assert "--more-episodes 4: curriculum.kind = 'multiplicative' derives λ's growth from run.episodes" in \
        capsys.readouterr().err
    assert stored_files(run_dir.path) == before and run_dir.summary()["episodes"] == 8


@pytest.mark.parametrize(("request_args", "named"), [
    ({"resume_dir": "runs/x", "more_episodes": -1}, "--more-episodes must be >= 0, got -1"),
    ({"more_episodes": 5}, "--more-episodes 5 trains a run further: give the run"),
])
def test_more_episodes_is_refused_negative_or_without_a_run(request_args, named):
    from cmcl.run.flags import RunRequestError

    with pytest.raises(RunRequestError, match=named):
        RunRequest(runner="inline", **request_args)


@pytest.mark.parametrize("value", ["0", "-1"])
@pytest.mark.parametrize("command", ["python -m cmcl train", "python -m services.launch"])
def test_num_cpus_must_be_a_positive_integer(command, value, tmp_path, capsys):
    """Bad worker counts are refused: 0 silently meant all cores and -1 was a traceback from Ray."""
    from services.launch import main as launch

    flags = ["--num-cpus", value, "--config", str(tmp_path / "absent.toml"), "--set", f"run.dir={tmp_path / 'run'}"]
    assert (main(["train", *flags]) if command.endswith("cmcl train") else launch(flags)) == 2
    assert capsys.readouterr().err == f"error: --num-cpus must be a positive integer (CPUs of the embedded Ray), " \
                                      f"got {value}\n"
    assert not (tmp_path / "run").exists()


def test_evaluate_finds_the_newest_policy(tmp_path, tiny_config):
    run_dir = trained_run(tiny_config, tmp_path / "run")
    evaluated = run_cli("evaluate", str(run_dir.path), "--episodes", "8", "--no-gif")
    assert evaluated.returncode == 0, evaluated.stderr
    result = evaluation_json(evaluated.stdout)
    assert result["policy"] == "trained" and result["episodes"] == 8
    assert Path(result["checkpoint"]) == run_dir.service_dir / f"learner-{learner_generations(run_dir)[0]:06d}.pt"


@pytest.mark.parametrize(("argv", "named"), [
    (["fit"], "invalid choice: 'fit'"),
    (["train", "--runner", "ray"], "argument --runner: invalid choice: 'ray'"),
    (["resume", "RUN", "--runner", "cluster"], "argument --runner: invalid choice: 'cluster'"),
    ([], "the following arguments are required"),
])
def test_an_unknown_verb_or_runner_is_refused_naming_it(argv, named, tmp_path, tiny_config, capsys):
    run_dir = trained_run(tiny_config, tmp_path / "run")
    before = stored_files(run_dir.path)
    with pytest.raises(SystemExit) as exit_:
        main([str(run_dir.path) if a == "RUN" else a for a in argv])
    assert exit_.value.code == 2 and named in capsys.readouterr().err
    assert stored_files(run_dir.path) == before


def test_resume_of_a_folder_that_is_not_a_run_names_it_and_leaves_it_alone(tmp_path, capsys):
    folder = tmp_path / "notes"
    folder.mkdir()
    (folder / "results.txt").write_text("keep me")
    assert main(["resume", str(folder)]) == 2
    assert f"{str(folder)!r} is not a run directory (no config.toml)" in capsys.readouterr().err
    assert sorted(p.name for p in folder.iterdir()) == ["results.txt"]
    assert (folder / "results.txt").read_text() == "keep me"


def test_either_runner_resumes_a_run_of_either(tmp_path, tiny_config, capsys):
    """One checkpoint format: the service takes the inline runner's run (its resume is opened without a word, here
    without starting Ray), and the inline runner goes on with a run the service wrote (its summary names the
    service, so a plain `resume` would start the service: --runner inline)."""
    run_dir = trained_run(tiny_config, tmp_path / "run")
    config, opened, lock = open_run(RunRequest(runner="service", resume_dir=str(run_dir.path), more_episodes=4,
                                               quiet=True))
    lock.release()
    assert opened.path == run_dir.path and config.run.episodes == 8
    run_dir.write_summary({**run_dir.summary(), "runner": "service"})
    assert runner_of(run_dir) == "service"
    assert main(["resume", str(run_dir.path), "--runner", "inline", "--more-episodes", "4", "--quiet",
                 "--no-eval"]) == 0, capsys.readouterr().err
    assert [r["episodes"] for r in run_dir.rows("episode")] == list(range(1, 9))
    assert run_dir.summary()["runner"] == "inline" and learner_generations(run_dir)[0] == 2


def test_a_run_of_the_old_inline_format_and_a_service_flag_for_the_inline_runner_are_refused(tmp_path, tiny_config,
                                                                                              capsys):
    """A run directory holding checkpoints of the inline runner's own format (checkpoints/ckpt_*.pt, before one
    runner): refused in one line naming the last commit that reads them, on either runner, left untouched."""
    path = tmp_path / "run"
    run_dir = RunDirectory.create(path, tiny_config("maddpg", dir=str(path), episodes=4))
    (run_dir.checkpoints / "ckpt_00000004.pt").write_bytes(b"an old inline checkpoint")
    run_dir.log({"kind": "episode", "episodes": 4})
    before = stored_files(run_dir.path)
    assert runner_of(run_dir) == "inline"
    for runner in ([], ["--runner", "inline"], ["--runner", "service"]):
        assert main(["resume", str(path), *runner, "--quiet", "--no-eval"]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"error: {path} holds checkpoints of the inline runner's own format ") and \
            f"commit {LAST_OWN_INLINE_FORMAT}" in err and err.count("\n") == 1, err
    assert LAST_OWN_INLINE_FORMAT == "8dbaee8"
    assert main(["train", "--runner", "inline", "--address", "auto", "--set", f"run.dir={tmp_path / 'new'}"]) == 2
    assert "--address auto is a flag of the service runner" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()
    assert stored_files(run_dir.path) == before


def test_the_runner_of_a_run_without_a_checkpoint_comes_from_its_summary_or_must_be_given(tmp_path, tiny_config):
    run_dir = RunDirectory.create(tmp_path / "run", tiny_config("maddpg", dir=str(tmp_path / "run")))
    with pytest.raises(ValueError, match="cannot tell which runner wrote .*pass --runner inline or --runner service"):
        runner_of(run_dir)
    run_dir.write_summary({"runner": "inline", "ended": "SIGINT"})
    assert runner_of(run_dir) == "inline"
    with pytest.raises(ValueError, match="--num-cpus 2 is a flag of the service runner"):
        RunRequest(runner="inline", num_cpus=2)
    with pytest.raises(ValueError, match="--runner must be one of inline, service, got 'ray'"):
        RunRequest(runner="ray")


def test_the_printed_python_is_the_one_a_user_can_type_where_it_is_printed(tmp_path, monkeypatch):
    """`python` when that is this interpreter on PATH; else its path (an un-activated venv after `make run`)."""
    here = Path(sys.executable)
    monkeypatch.setenv("PATH", str(tmp_path))  # no python on PATH at all
    monkeypatch.chdir(here.parent)
    assert python_command() == f"./{here.name}"  # relative to the working directory (a bare name means PATH)
    monkeypatch.chdir(tmp_path)
    typed = python_command()
    assert Path(typed).is_absolute() or (tmp_path / typed).resolve() == here.resolve()
    done = subprocess.run([*shlex.split(typed), "-c", "import sys; print(sys.prefix)"], capture_output=True, text=True)
    assert done.stdout.strip() == sys.prefix, "the printed interpreter is another environment"
    if here.name == "python":
        monkeypatch.setenv("PATH", str(here.parent))
        assert python_command() == "python"


def test_a_key_of_an_older_layout_is_refused_in_one_line_and_nothing_is_made(tmp_path, capsys):
    run = tmp_path / "run"
    old_key = "teachers.difficulty_norm=max"
    assert main(["train", "--runner", "inline", "--set", f"run.dir={run}", "--set", old_key]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: unknown key teachers.difficulty_norm") and err.count("\n") == 1, err
    assert not run.exists()


def test_a_run_written_before_the_priority_tables_is_refused_naming_the_key_and_the_last_commit(tmp_path,
                                                                                                tiny_config, capsys):
    """A run directory whose config.toml has a key of the layout before [teams.<team>.priority]
    (teachers.difficulty_norm): resume and evaluate refuse it in one line naming the key and the commit that reads
    it, and leave it untouched."""
    from cmcl.replay.snapshot import LAST_READER

    path = tmp_path / "run"
    run_dir = trained_inline_run(tiny_config("per", dir=str(path), episodes=4))
    text = run_dir.config_path.read_text()
    assert "\n[teachers]\n" in text
    run_dir.config_path.write_text(text.replace("\n[teachers]\n", '\n[teachers]\ndifficulty_norm = "max"\n'))
    before = stored_files(run_dir.path)
    for argv in (["resume", str(path), "--more-episodes", "4", "--quiet", "--no-eval"],
                 ["evaluate", str(path), "--episodes", "4", "--no-gif"]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and "unknown key teachers.difficulty_norm: written by an older version; " \
            f"commit {LAST_READER} is the last that reads it" in err and err.count("\n") == 1, err
    assert stored_files(run_dir.path) == before

"""Keys only one runner honours (cmcl/config/runners.py): refused on the other runner's command line in one line
naming the key, the runner and the value (exit 2, nothing made); a config file may carry the other runner's own
settings (not read, said in a note), except one that changes what is learned; every shipped preset, the grids'
commands and the Makefile's run still load on the runners they are run with."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pytest

from cmcl.__main__ import main
from cmcl.config import Config, ConfigError, apply_overrides, config_from_dict, load_config, load_data
from cmcl.config.runners import RUNNER_ONLY, check_runner_keys, runner_key
from cmcl.loop.__main__ import main as loop_main
from services.launch import main as launch_main

ROOT = Path(__file__).resolve().parents[1]
PRESETS = sorted((ROOT / "configs").glob("*.toml")) + sorted((ROOT / "configs" / "paper").glob("*.toml"))
OTHER = {"inline": "service", "service": "inline"}
# one non-default value of every key of the table (a [service] key stands for its section)
NON_DEFAULT = {"service.rollout_workers": 2, "service.metrics_port": 0, "run.checkpoint_every": 20,
               "run.log_every": 8, "teachers.rescore_rows_per_update": 64, "icm.intrinsic_reward_coef": 0.1}


def check(runner, file_data=None, overrides=()):
    """The check as `open_run` makes it; returns the notes it made."""
    notes = []
    config = config_from_dict(apply_overrides(file_data or {}, overrides))
    check_runner_keys(config, runner, file_data, overrides, note=notes.append)
    return notes


def test_the_table_names_real_keys_and_every_key_of_the_service_section():
    sections = {f.name: getattr(Config(), f.name) for f in dataclasses.fields(Config) if f.name != "teams"}
    for key in RUNNER_ONLY:
        section, name = key.split(".")
        assert name == "*" or name in {f.name for f in dataclasses.fields(sections[section])}, key
    assert all(runner_key(f"service.{f.name}").runner == "service" for f in dataclasses.fields(Config().service))
    assert runner_key("run.episodes") is None and runner_key("maddpg.update_every") is None
    assert {runner_key(k).runner for k in NON_DEFAULT} == {"inline", "service"}
    assert all(runner_key(k) is not None for k in NON_DEFAULT)
    from services.supervisor import REPORT_EVERY_S  # what the table says the service does instead is what it does

    assert f"every {REPORT_EVERY_S:g} s" in RUNNER_ONLY["run.log_every"].instead


@pytest.mark.parametrize("key", sorted(NON_DEFAULT))
def test_a_set_key_the_runner_ignores_is_refused_naming_key_runner_and_value(key):
    honoured = runner_key(key).runner
    override = f"{key}={NON_DEFAULT[key]}"
    with pytest.raises(ConfigError) as err:
        check(OTHER[honoured], overrides=[override])
    text = str(err.value)
    assert text.startswith(f"{key} is honoured by the {honoured} runner only, not the {OTHER[honoured]} runner (")
    assert text.endswith(f", got {NON_DEFAULT[key]!r}") and f"--runner {honoured}" in text and "\n" not in text
    assert check(honoured, overrides=[override]) == []  # the runner that honours it
    default = getattr(getattr(Config(), key.split(".")[0]), key.split(".")[1])
    assert check(OTHER[honoured], overrides=[f"{key}={default!r}"]) == []  # its default: nothing asked


def test_a_config_file_may_carry_the_other_runners_own_settings_but_not_a_learning_change():
    file = {"service": {"rollout_workers": 2}, "run": {"checkpoint_every": 20, "log_every": 8},
            "teachers": {"rescore_rows_per_update": 64}}
    assert check("inline", file) == []  # the [service] section is the service's: not read inline, nothing to say
    (note,) = check("service", file)
    assert note.startswith("note: the service runner does not read the config file's run.checkpoint_every = 20 (")
    assert "run.log_every = 8" in note and "teachers.rescore_rows_per_update = 64" in note
    assert "service.checkpoint_every_s" in note and "service.score_rows_per_call" in note
    with pytest.raises(ConfigError, match=r"^icm\.intrinsic_reward_coef is honoured by the inline runner only"):
        check("service", {"icm": {"intrinsic_reward_coef": 0.1}})
    assert check("inline", {"icm": {"intrinsic_reward_coef": 0.1}}) == []
    with pytest.raises(ConfigError, match=r"^run\.log_every is honoured"):  # on the command line it is refused
        check("service", file, ["run.log_every=4"])


@pytest.mark.parametrize("path", PRESETS, ids=lambda p: str(p.relative_to(ROOT / "configs")))
@pytest.mark.parametrize("runner", ["inline", "service"])
def test_every_shipped_preset_loads_on_both_runners(path, runner):
    notes = check(runner, load_data(path))
    assert len(notes) <= 1 and (runner == "service" or not notes)


def test_every_grid_run_passes_the_check_of_its_runner(tmp_path):
    """The experiments' command lines (experiments.runner.command) of every grid, on the runner each run names."""
    from experiments.grids import GRIDS, grid
    from experiments.runner import command
    from tests.test_confirm import fake_screen  # fake summaries: the confirm grid's arms come from a screen

    screen = fake_screen(tmp_path / "screen")
    runs = grid([g for g in GRIDS if g != "screen"], [0], screen=screen) + grid(["screen"], [100], screen=screen)
    for run in runs:  # the screen's seeds are its own (experiments.screen_arms); round one runs every arm
        if run.source is not None:
            continue
        argv = command(run, tmp_path / run.id)
        sets = [argv[i + 1] for i, a in enumerate(argv) if a == "--set"]
        file = argv[argv.index("--config") + 1] if "--config" in argv else None
        mode = "inline" if "cmcl.loop" in argv[2] or "--runner" in argv and argv[argv.index("--runner") + 1] == \
            "inline" else "service"
        assert mode == run.mode, run.id
        check(mode, load_data(file), sets)


def test_the_makefiles_run_loads_on_the_service():
    recipe = (ROOT / "Makefile").read_text().split("\nrun: install\n")[1].split("\n\n")[0]
    words = recipe.replace("\\\n", " ").split()
    assert words[words.index("--runner") + 1] == "service"
    sets = [words[i + 1] for i, w in enumerate(words) if w == "--set" and "$(" not in words[i + 1]]
    assert check("service", load_data(ROOT / words[words.index("--config") + 1]), sets) == []
    # the README's "the paper's CMCL is one flag away": make run RUN_ARGS="--set teams.agent.algorithm=cmcl"
    readme = (ROOT / "README.md").read_text()
    flag = 'make run RUN_ARGS="--set teams.agent.algorithm=cmcl"'
    assert flag in readme
    path = ROOT / words[words.index("--config") + 1]
    assert check("service", load_data(path), [*sets, "teams.agent.algorithm=cmcl"]) == []
    assert load_config(path, [*sets, "teams.agent.algorithm=cmcl"]).teams["agent"].algorithm == "cmcl"


@pytest.mark.parametrize(("argv", "key", "runner"), [
    (["train", "--runner", "inline", "--set", "service.rollout_workers=2"], "service.rollout_workers", "inline"),
    (["train", "--set", "run.checkpoint_every=20"], "run.checkpoint_every", "service"),  # the default runner
    (["train", "--runner", "service", "--set", "teachers.rescore_rows_per_update=64"],
     "teachers.rescore_rows_per_update", "service"),
])
def test_the_command_line_refuses_in_one_line_before_anything_is_made(argv, key, runner, tmp_path, capsys):
    run = tmp_path / "run"
    assert main([*argv, "--set", f"run.dir={run}"]) == 2
    err = capsys.readouterr().err
    assert re.fullmatch(rf"error: {re.escape(key)} is honoured by the \w+ runner only, not the {runner} runner "
                        r"\(.+\); leave it out or train with --runner \w+, got \d+\n", err), err
    assert not run.exists()


def test_the_aliases_and_resume_refuse_alike(tmp_path, tiny_config, capsys):
    from cmcl.io.rundir import RunDirectory
    from cmcl.loop import InlineLoop

    assert loop_main(["--set", "service.updates_per_call=4", "--set", f"run.dir={tmp_path / 'a'}"]) == 2
    assert launch_main(["--set", "run.log_every=4", "--set", f"run.dir={tmp_path / 'b'}"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("error: service.updates_per_call is honoured by the service runner only, not the inline")
    assert err[1].startswith("error: run.log_every is honoured by the inline runner only, not the service runner")
    config = tiny_config("maddpg", dir=str(tmp_path / "run"), episodes=4, checkpoint_every=4)
    run_dir = RunDirectory.create(config.run.dir, config)
    InlineLoop(config, run_dir, progress=None).run()
    before = run_dir.metrics_path.read_bytes()
    assert main(["resume", config.run.dir, "--set", "service.slack_updates=8", "--quiet", "--no-eval"]) == 2
    assert capsys.readouterr().err.startswith("error: service.slack_updates is honoured by the service runner only")
    assert run_dir.metrics_path.read_bytes() == before
    stored = load_config(run_dir.config_path)  # its stored cadence (inline) is the run's own: resumed without a word
    assert stored.run.checkpoint_every == 4
    assert main(["resume", config.run.dir, "--set", "run.log_every=2", "--more-episodes", "2", "--quiet",
                 "--no-eval"]) == 0

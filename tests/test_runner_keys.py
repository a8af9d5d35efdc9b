"""Which runner honours which key (cmcl/config/runners.py).

Both runners schedule the same roles (services.runtime.calls), so every key is read by both but the service's Ray-only
ones (SERVICE_ONLY: restarts, call timeouts, CPU requests, the metrics endpoint): those are refused on the inline
runner's command line in one line naming the key, the runner and the value (exit 2, nothing made), and not read
there from a config file. Every other service.* key (service.updates_per_call, ...) is accepted inline. Every shipped
preset, the grids' commands and the Makefile's run still load on the runners they are run with."""

from __future__ import annotations

import dataclasses
import importlib.util
import re
from pathlib import Path

import pytest

from cmcl.__main__ import main
from cmcl.config import Config, ConfigError, apply_overrides, config_from_dict, load_config, load_data
from cmcl.config.runners import SERVICE_ONLY, check_runner_keys
from cmcl.run.rundir import RunDirectory
from services.launch import main as launch_main

ROOT = Path(__file__).resolve().parents[1]
PRESETS = sorted((ROOT / "configs").glob("*.toml")) + sorted((ROOT / "configs" / "paper").glob("*.toml"))
# one non-default value of every service-only key
SERVICE_ONLY_VALUES = {"service.max_restarts": 5, "service.call_timeout_s": 30.0, "service.rollout_resource": "gpu",
                       "service.rollout_cpus": 0.5, "service.learner_cpus": 1.0, "service.teacher_cpus": 0.5,
                       "service.icm_cpus": 0.5, "service.replay_cpus": 0.5, "service.metrics_port": 0,
                       "service.metrics_host": "0.0.0.0"}
# one non-default value of service keys both runners honour
SHARED_VALUES = {"service.updates_per_call": 4, "service.fit_steps_per_call": 2, "service.score_rows_per_call": 200,
                 "service.checkpoint_every_s": 5.0, "service.rollout_workers": 2}


def check(runner, file_data=None, overrides=()):
    """The check as `open_run` makes it (on the config the file and overrides resolve to)."""
    config = config_from_dict(apply_overrides(file_data or {}, overrides))
    check_runner_keys(config, runner, file_data, overrides)
    return config


def override(key, value):
    return f"{key}={value!r}"


def default_of(key):
    section, name = key.split(".")
    return getattr(getattr(Config(), section), name)


def test_the_service_only_keys_are_real_service_keys_and_the_others_are_both_runners():
    service = {f.name for f in dataclasses.fields(Config().service)}
    assert SERVICE_ONLY == set(SERVICE_ONLY_VALUES)
    assert {key.split(".")[1] for key in SERVICE_ONLY} < service
    assert all(key.startswith("service.") for key in SERVICE_ONLY)
    assert {"updates_per_call", "fit_steps_per_call", "score_rows_per_call", "checkpoint_every_s"} <= \
        service - {key.split(".")[1] for key in SERVICE_ONLY}
    assert all(value != default_of(key) for key, value in {**SERVICE_ONLY_VALUES, **SHARED_VALUES}.items())


@pytest.mark.parametrize("key", sorted(SERVICE_ONLY_VALUES))
def test_a_service_only_key_set_for_the_inline_runner_is_refused_naming_key_runner_and_value(key):
    value = SERVICE_ONLY_VALUES[key]
    with pytest.raises(ConfigError) as err:
        check("inline", overrides=[override(key, value)])
    text = str(err.value)
    assert text.startswith(f"{key} is honoured by the service runner only, not the inline runner (")
    assert text.endswith(f", got {value!r}") and "--runner service" in text and "\n" not in text
    assert getattr(check("service", overrides=[override(key, value)]).service, key.split(".")[1]) == value
    check("inline", overrides=[override(key, default_of(key))])  # its default: nothing asked


@pytest.mark.parametrize("key", sorted(SHARED_VALUES))
def test_the_other_service_keys_are_honoured_inline(key):
    value = SHARED_VALUES[key]
    for runner in ("inline", "service"):
        assert getattr(check(runner, overrides=[override(key, value)]).service, key.split(".")[1]) == value


def test_a_config_file_may_carry_the_services_own_settings_for_the_inline_runner():
    """A file describes a run for either runner (the deploy files' CPU requests): not read inline, not refused."""
    file = {"service": {"learner_cpus": 1.0, "max_restarts": 5, "updates_per_call": 4}}
    assert check("inline", file).service.updates_per_call == 4
    assert check("service", file).service.learner_cpus == 1.0
    with pytest.raises(ConfigError, match=r"^service\.max_restarts is honoured by the service runner only"):
        check("inline", file, ["service.max_restarts=7"])  # on the command line it is refused


@pytest.mark.parametrize("path", PRESETS, ids=lambda p: str(p.relative_to(ROOT / "configs")))
@pytest.mark.parametrize("runner", ["inline", "service"])
def test_every_shipped_preset_loads_on_both_runners(path, runner):
    data = load_data(path)
    check(runner, data)
    load_config(path)


def test_every_grid_run_passes_the_check_of_its_runner(tmp_path, monkeypatch):
    """The experiments' command lines (experiments.runner.command) of every grid, on the runner each run names."""
    from experiments import grids
    from experiments.grids import GRIDS, grid
    from experiments.runner import command
    from experiments.store import ResultsStore
    from tests.test_confirm import fake_screen  # fake summaries: the confirm grid's arms come from a screen
    from tests.test_sparse_confirm import every_candidate, synthetic_scale, synthetic_screen  # the same, sparse

    screen = fake_screen(tmp_path / "screen")
    for name in ("sparse_screen", "sparse_scale"):  # a curriculum chosen on one task, curiosity on the other
        monkeypatch.setitem(grids.GRIDS, name, tmp_path / name)
    for summary in synthetic_screen(every_candidate("vacl_n4") | {("vacl_n4", "radius_progress"): 0.5}
                                    | every_candidate("push_box") | {("push_box", "intrinsic_strong"): 0.1}):
        ResultsStore(tmp_path / "sparse_screen").write(summary)
    for summary in synthetic_scale("push_box", "intrinsic_strong"):
        ResultsStore(tmp_path / "sparse_scale").write(summary)
    runs = grid([g for g in GRIDS if g != "screen"], [0], screen=screen) + grid(["screen"], [100], screen=screen)
    for run in runs:  # the screen's seeds are its own (experiments.screen_arms); round one runs every arm
        if run.source is not None:
            continue
        argv = command(run, tmp_path / run.id)
        assert argv[1] == "-m" and importlib.util.find_spec(argv[2]) is not None, (run.id, argv[:3])
        sets = [argv[i + 1] for i, a in enumerate(argv) if a == "--set"]
        file = argv[argv.index("--config") + 1] if "--config" in argv else None
        mode = argv[argv.index("--runner") + 1] if "--runner" in argv else "service"
        assert mode == run.mode, run.id
        check(mode, load_data(file), sets)


def test_the_makefiles_run_loads_on_the_service():
    recipe = (ROOT / "Makefile").read_text().split("\nrun: install\n")[1].split("\n\n")[0]
    words = recipe.replace("\\\n", " ").split()
    assert words[words.index("--runner") + 1] == "service"
    sets = [words[i + 1] for i, w in enumerate(words) if w == "--set" and "$(" not in words[i + 1]]
    path = ROOT / words[words.index("--config") + 1]
    check("service", load_data(path), sets)
    # the README's "the paper's CMCL is one flag away": make run RUN_ARGS="--set teams.agent.algorithm=cmcl"
    readme = (ROOT / "README.md").read_text()
    assert 'make run RUN_ARGS="--set teams.agent.algorithm=cmcl"' in readme
    check("service", load_data(path), [*sets, "teams.agent.algorithm=cmcl"])
    assert load_config(path, [*sets, "teams.agent.algorithm=cmcl"]).teams["agent"].algorithm == "cmcl"


@pytest.mark.parametrize(("argv", "error"), [
    (["train", "--runner", "inline", "--set", "service.max_restarts=5"],
     r"service\.max_restarts is honoured by the service runner only, not the inline runner \(.+\); leave it out or "
     r"train with --runner service, got 5"),
    (["train", "--set", "run.checkpoint_every=20"],  # the default runner
     r"unknown key run\.checkpoint_every \(known: .+\)"),
])
def test_the_command_line_refuses_in_one_line_before_anything_is_made(argv, error, tmp_path, capsys):
    run = tmp_path / "run"
    assert main([*argv, "--set", f"run.dir={run}"]) == 2
    err = capsys.readouterr().err
    assert re.fullmatch(rf"error: {error}\n", err), err
    assert not run.exists()


def test_the_alias_and_resume_refuse_alike_and_a_shared_key_resumes_inline(tmp_path, tiny_config, capsys):
    from services.launch import train_in_process

    assert launch_main(["--set", "run.log_every=4", "--set", f"run.dir={tmp_path / 'b'}"]) == 2
    assert capsys.readouterr().err.startswith("error: unknown key run.log_every (known: ")
    assert not (tmp_path / "b").exists()
    config = tiny_config("maddpg", dir=str(tmp_path / "run"), episodes=4)
    run_dir = RunDirectory.create(config.run.dir, config)
    train_in_process(config, run_dir)
    before = run_dir.metrics_path.read_bytes()
    resume = ["resume", config.run.dir, "--runner", "inline", "--quiet", "--no-eval"]
    assert main([*resume, "--set", "service.max_restarts=5"]) == 2
    assert capsys.readouterr().err.startswith("error: service.max_restarts is honoured by the service runner only")
    assert main([*resume, "--set", "run.log_every=2"]) == 2
    assert capsys.readouterr().err.startswith("error: unknown key run.log_every (known: ")
    assert run_dir.metrics_path.read_bytes() == before
    assert main([*resume, "--set", "service.updates_per_call=4", "--more-episodes", "2"]) == 0
    assert [r["episodes"] for r in run_dir.rows("episode")][-1] >= 6
    assert run_dir.summary()["runner"] == "inline"

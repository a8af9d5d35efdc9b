"""The service's roles built in-process, without Ray, for the tests that drive them by hand chunk by chunk
(tests/test_service_inprocess_flow.py, tests/test_service_inprocess_restart.py, tests/test_agreement.py)."""

from services.roles.icm import ICMWorker
from services.roles.learner import Learner
from services.roles.replay_server import ReplayServer
from services.roles.rollout import RolloutWorker
from services.roles.teachers import TeacherWorker
from tests.tiny import make_tiny_config

# The roles are driven by hand here, chunk by chunk, on the tiny service config with: a 360-row buffer (3 chunks of
# 4 worlds × 30 steps), calls of 4 updates / 2 teacher fit steps / 200 scored rows, and the presets' 20 000 episodes
# (the default λ stride reaches λ_max at half of run.episodes: with 12 episodes λ would reach it within 3 chunks).
IN_PROCESS_SECTIONS = {"replay": {"capacity": 360},
                       "service": {"updates_per_call": 4, "fit_steps_per_call": 2, "score_rows_per_call": 200}}


def in_process_config(algorithm="cmcl", **sections):
    """The roles' config dict (`Config.to_dict()`): the tiny service config with `IN_PROCESS_SECTIONS`, then
    `sections` ({key: value} per section name) on top."""
    merged = {name: {**IN_PROCESS_SECTIONS.get(name, {}), **sections.get(name, {})}
              for name in {*IN_PROCESS_SECTIONS, *sections}}
    return make_tiny_config(algorithm, service=True, sections=merged, episodes=20_000).to_dict()


def roles(cfg):
    """(replay server, learner, rollout worker 0, [one teacher actor per fold], ICM worker) of the config dict `cfg`,
    each the class the service runs as a Ray actor, built here as a plain object."""
    k = cfg["teachers"]["num_folds"]
    teachers = [TeacherWorker(cfg, [i], i) for i in range(k)]
    return ReplayServer(cfg), Learner(cfg, 0), RolloutWorker(cfg, 0, 0), teachers, ICMWorker(cfg, 0)


def train_tiny(config, directory, episodes=None, resume=False, **run):
    """Train `config` (a cmcl.config.Config) with the inline runner in this process (services.launch.train_in_process)
    into `directory`: a new run, or with `resume` the run already there, continued to `episodes` (its stored
    config's otherwise). `run`: further run-section values of a new run. Returns (summary, roles)."""
    from cmcl.config import config_from_dict
    from cmcl.run.rundir import RunDirectory
    from services.launch import train_in_process

    if resume:
        run_dir = RunDirectory.open(directory)
        config = run_dir.config(() if episodes is None else (f"run.episodes={episodes}",))
        return train_in_process(config, run_dir, resume=True)
    data = config.to_dict()
    data["run"] = {**data["run"], **({} if episodes is None else {"episodes": episodes}), **run,
                   "dir": str(directory)}
    config = config_from_dict(data)
    return train_in_process(config, RunDirectory.create(config.run.dir, config))


def trained_inline_run(config):
    """A finished run of `config` in its run.dir, as `python -m cmcl train --runner inline --quiet --no-eval` leaves
    it (the service's checkpoint files, summary.json naming the inline runner), trained in this process; its config
    file is written beside the run directory (<run.dir>.toml). Returns the RunDirectory."""
    from pathlib import Path

    from cmcl.__main__ import main
    from cmcl.config import dump_toml
    from cmcl.run.rundir import RunDirectory

    path = Path(config.run.dir)
    file = path.with_name(f"{path.name}.toml")
    file.write_text(dump_toml(config))
    assert main(["train", "--runner", "inline", "--config", str(file), "--quiet", "--no-eval"]) == 0
    return RunDirectory.open(path)

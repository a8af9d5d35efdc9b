"""The task curriculum over a world setting (cmcl.rollout.task_curriculum, [task_curriculum]): the rollout worker's
stage advances when its episodes' success crosses the level (a real navigation twin whose stage-0 cover radius makes
every episode a success: the signal is controlled through the world, the role is the real one), the rules' windows,
the mix of earlier stages, one-line errors at config load, and tiny runs of both runners with a resume that keeps
the stage."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cmcl.config import ConfigError, TaskCurriculumConfig, load_config
from cmcl.rollout.task_curriculum import TaskCurriculum
from cmcl.run.plots import episode_series
from cmcl.run.rundir import RunDirectory
from experiments.own_envs import stage_spans
from services.roles.rollout import RolloutWorker
from tests.in_process import train_tiny
from tests.tiny import tiny_overrides

ROOT = Path(__file__).resolve().parents[1]
VACL = ROOT / "configs" / "vacl_n4_maddpg.toml"
# stage 0: a cover radius spanning the world (every landmark covered from the first step: success 1), stage 1 the
# source's 0.15 (a random policy's success is 0 there)
EASY_THEN_SOURCE = ['task_curriculum.param="cover_radius"', "task_curriculum.stages=[10.0, 0.15]",
                    "task_curriculum.level=0.8", "task_curriculum.window=8"]
SHORT = ["env.num_envs=4", "env.episode_length=5"]


def _config(*sets, service=False):
    tiny = [s for s in tiny_overrides(service=service) if not s.startswith("env.")]
    return load_config(VACL, [*tiny, *SHORT, "run.max_seconds=0", *sets])


def _stages(worker, calls):
    out = []
    for _ in range(calls):
        _, report = worker.rollout(None)
        out.append(report.rollout.finished.task_stage.tolist())
    return out


def test_the_rollout_worker_advances_when_the_success_average_reaches_the_level():
    worker = RolloutWorker(_config(*EASY_THEN_SOURCE).to_dict(), 0, 0)
    played = _stages(worker, 4)  # 4 episodes per call; the window of 8 is full after two
    assert played[0] == [0.0] * 4 and played[1] == [0.0] * 4
    assert worker.curriculum.stage == 1 and worker.curriculum.advanced_at == [8]
    assert played[3] == [1.0] * 4  # every world restarted at the new stage within one episode
    assert worker.env.world_settings()["cover_radius"].tolist() == pytest.approx([0.15] * 4)


def test_the_stage_stays_while_the_success_average_is_below_the_level():
    worker = RolloutWorker(_config('task_curriculum.param="cover_radius"', "task_curriculum.stages=[0.01, 0.15]",
                                   "task_curriculum.window=8").to_dict(), 0, 0)
    assert _stages(worker, 4)[-1] == [0.0] * 4 and worker.curriculum.stage == 0


def _curriculum(**fields):
    return TaskCurriculum(TaskCurriculumConfig(param="spawn_scale", stages=(0.1, 0.5, 1.0), **fields), 4,
                          np.random.default_rng(0))


def test_fixed_advances_every_window_whatever_the_signal():
    c = _curriculum(advance="fixed", window=5)
    assert not c.record(np.zeros(4, np.int64), np.zeros(4))
    assert c.record(np.zeros(4, np.int64), np.zeros(4)) and c.stage == 1 and c.advanced_at == [5]


def test_episodes_of_other_stages_do_not_count_and_the_last_stage_is_kept():
    c = _curriculum(window=2, level=0.5)
    assert not c.record(np.array([1, 1, 2]), np.ones(3))  # none played at the current stage 0
    assert c.record(np.array([0, 0]), np.ones(2)) and c.stage == 1
    assert c.record(np.array([1, 1]), np.ones(2)) and c.stage == 2
    assert not c.record(np.array([2, 2, 2]), np.ones(3)) and c.stage == 2


def test_progress_advances_once_the_rising_success_levels_off():
    c = _curriculum(advance="progress", window=4, level=0.1)
    zeros = np.zeros(4, np.int64)
    assert not c.record(zeros, np.zeros(4)) and not c.record(zeros, np.zeros(4))  # flat at 0: no progress to judge
    assert not c.record(zeros, np.array([1.0, 1, 0, 0]))  # rising: 0 -> 0.5
    assert c.record(zeros, np.array([1.0, 0, 1, 0])) and c.stage == 1  # 0.5 -> 0.5: levelled off


def test_mix_draws_earlier_stages_for_that_share_of_episodes():
    class Env:
        def set_world_settings(self, name, idx, values):
            self.values = values

    c = _curriculum(window=1, level=0.5, mix=1.0)
    c.record(np.array([0, 1]), np.ones(2))
    assert c.stage == 2
    env = Env()
    c.start(env)
    assert set(c.next_stage.tolist()) <= {0, 1} and set(env.values.tolist()) <= {0.1, 0.5}


@pytest.mark.parametrize("sets,match", [
    (['task_curriculum.param="spawnscale"', "task_curriculum.stages=[0.1, 1.0]"],
     r"task_curriculum.param = 'spawnscale': not a setting of .*spawn_scale"),
    (['task_curriculum.param="spawn_scale"', "task_curriculum.stages=[-1.0, 1.0]"],
     r"task_curriculum.stages\[0\] = -1.0: spawn_scale must be a number in \(0, 10\]"),
    (['task_curriculum.param="gate"', "task_curriculum.stages=[1.5, 4.0]"],
     r"task_curriculum.stages\[0\] = 1.5: gate must be an integer"),
    (['task_curriculum.param="spawn_scale"', "task_curriculum.stages=[1.0]"], r"task_curriculum.stages must hold"),
    (["task_curriculum.stages=[0.5, 1.0]"], r"task_curriculum.stages needs task_curriculum.param"),
    (['task_curriculum.advance="sometimes"'], r"task_curriculum.advance must be one of"),
])
def test_a_bad_param_or_value_is_refused_in_one_line_naming_it(sets, match):
    with pytest.raises(ConfigError, match=match) as err:
        load_config(VACL, sets)
    assert "\n" not in str(err.value)


def test_push_box_and_the_built_in_tasks_take_their_own_settings_only():
    load_config(ROOT / "configs" / "push_box_maddpg.toml",
                ['task_curriculum.param="push_cells"', "task_curriculum.stages=[1, 3, 6]"])
    with pytest.raises(ConfigError, match="has no settable world parameters"):
        load_config(None, ['task_curriculum.param="spawn_scale"', "task_curriculum.stages=[0.5, 1.0]"])


def _stage_rows(run_dir):
    return [int(r["task_stage"]) for r in RunDirectory.open(run_dir).rows("episode")]


def test_the_inline_runner_trains_a_curriculum_and_its_resume_keeps_the_stage(tmp_path):
    config = _config(*EASY_THEN_SOURCE)
    summary, roles = train_tiny(config, tmp_path / "run", episodes=24)
    assert summary["episodes"] >= 24 and summary["updates"] > 0
    stages = _stage_rows(tmp_path / "run")
    assert stages[:8] == [0] * 8 and stages[-4:] == [1] * 4
    saved = json.loads((RunDirectory.open(tmp_path / "run").service_dir / "rollout_0.json").read_text())
    assert saved["task_curriculum"]["stage"] == 1
    train_tiny(None, tmp_path / "run", episodes=32, resume=True)
    assert _stage_rows(tmp_path / "run")[24:] == [1] * 8  # not back at stage 0
    spans = stage_spans(episode_series(RunDirectory.open(tmp_path / "run"))["task_stage"])  # what a summary keeps
    first = _stage_rows(tmp_path / "run").index(1)
    assert spans == [{"stage": 0, "first_episode": 0, "episodes_at_stage": first},
                     {"stage": 1, "first_episode": first, "episodes_at_stage": 32 - first}]


def test_a_curriculum_runs_summary_keeps_its_stage_spans_and_last_tenths_success(tmp_path):
    from experiments.measures import summarise
    from experiments.run_spec import Run

    train_tiny(_config(*EASY_THEN_SOURCE), tmp_path / "run", episodes=40)
    run = Run("sparse_screen_vacl_n4_curriculum_s0", "sparse_screen", "own_env", "maddpg", None, 0, 40,
              arm="curriculum", config="vacl_n4_curriculum.toml", env="vacl_n4")
    summary = summarise(run, tmp_path / "run")
    success = [r["success"] for r in RunDirectory.open(tmp_path / "run").rows("episode")]
    assert summary["final_tenth_success"] == pytest.approx(np.mean(success[-4:]))
    assert [s["stage"] for s in summary["task_stages"]] == [0, 1]
    assert summary["task_stages"][1]["first_episode"] == _stage_rows(tmp_path / "run").index(1)
    assert 0.0 <= summary["held_out_success"] <= 1.0 and "task_stage" in summary["curves"]


def test_stage_spans_count_each_stage_from_its_first_episode_without_the_mixed_earlier_ones():
    played = np.array([0, 0, 0, 1, 0, 1, 1, 2, 0, 1, 2, 2], np.float64)
    assert stage_spans(played) == [{"stage": 0, "first_episode": 0, "episodes_at_stage": 3},
                                   {"stage": 1, "first_episode": 3, "episodes_at_stage": 3},
                                   {"stage": 2, "first_episode": 7, "episodes_at_stage": 3}]
    assert stage_spans(np.zeros(5)) == [{"stage": 0, "first_episode": 0, "episodes_at_stage": 5}]


@pytest.mark.ray
def test_the_service_runner_trains_a_curriculum(tmp_path, ray_cluster):
    from services.launch import run_service

    config = _config(*EASY_THEN_SOURCE, f"run.dir={tmp_path / 'run'}", "run.episodes=24", service=True)
    summary = run_service(config, RunDirectory.create(config.run.dir, config), progress=None)
    assert summary["episodes"] >= 24
    stages = _stage_rows(tmp_path / "run")
    assert stages[0] == 0 and stages[-1] == 1


@pytest.mark.parametrize("task,kind", [("vacl_n4", "curriculum"), ("push_box", "curriculum"), ("vacl_n4", "radius"),
                                       ("vacl_n4", "intrinsic"), ("push_box", "intrinsic")])
def test_each_screen_preset_is_its_tasks_maddpg_preset_plus_one_section(task, kind):
    from cmcl.config import load_data

    base, data = (load_data(ROOT / "configs" / f"{task}_{k}.toml") for k in ("maddpg", kind))
    section = "icm" if kind == "intrinsic" else "task_curriculum"
    assert set(data) == set(base) | {section} and data["env"] == base["env"] and data["teams"] == base["teams"]
    assert data["run"]["max_seconds"] == base["run"]["max_seconds"]
    config = load_config(ROOT / "configs" / f"{task}_{kind}.toml")
    assert config.task_curriculum.enabled == (kind != "intrinsic")
    assert config.trains_icm == (kind == "intrinsic")
    if kind != "intrinsic":  # the last stage is the source task, the one held out
        setting = config.task_curriculum.param
        assert config.task_curriculum.stages[-1] == {"spawn_scale": 1.0, "push_cells": 6, "cover_radius": 0.15}[setting]


def test_the_sparse_screen_grid_has_every_candidate_of_each_running_round_at_its_seeds():
    from experiments.grids import grid
    from experiments.sparse_arms import SCREEN_ROUNDS, SPARSE_SCREEN_SEEDS

    runs = grid(["sparse_screen"], list(SPARSE_SCREEN_SEEDS))
    want = {f"sparse_screen_{task}_{c}_s{seed}" for task, rounds in SCREEN_ROUNDS.items() for r in rounds
            if not r.stopped for seed in r.seeds for c in r.candidates}
    assert runs and [r.id for r in runs] == sorted(want, key=[r.id for r in runs].index) and len(runs) == len(want)
    stopped = {f"sparse_screen_{task}_{c}_s{seed}" for task, rounds in SCREEN_ROUNDS.items() for r in rounds
               if r.stopped for seed in r.seeds for c in r.candidates}
    assert stopped and not stopped & {r.id for r in runs}  # a stopped round schedules nothing more
    assert [r.seed for r in runs] == sorted(r.seed for r in runs)
    for r in runs:
        config = load_config(ROOT / "configs" / r.config, list(r.sets))  # every candidate loads
        assert r.algorithm == "maddpg" and all(t.algorithm == "maddpg" for t in config.teams.values())
        assert r.max_seconds == 1800

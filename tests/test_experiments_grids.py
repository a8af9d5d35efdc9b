"""The grid registry (experiments.grids) and one run's measures (experiments.measures): the runs of each grid, and
the reading of a run's first episodes, the same-budget reference that a shorter ablation (the paper's schedule) is
compared with."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from cmcl.run.rundir import RunDirectory
from experiments.__main__ import build_parser, selected_runs
from experiments.grids import ABLATIONS, GRIDS, grid, prefix_reference_runs
from experiments.measures import summarise
from experiments.run_spec import ROOT, Run
from tests.in_process import train_tiny
from tests.tiny import make_tiny_config

ONE_UPDATE_PER_STEP = {"maddpg": {"update_every": 1}}


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    """A tiny CMCL navigation run of 12 episodes (the inline runner: the service's checkpoints, at its end)."""
    path = tmp_path_factory.mktemp("reproduce") / "spread_cmcl_s0"
    train_tiny(make_tiny_config("cmcl", service=True, sections=ONE_UPDATE_PER_STEP), path)
    return path


@pytest.mark.xfail(strict=True, raises=ValueError, reason="a prefix is held-out evaluated from the inline runner's "
                   "checkpoint at episode `upto` (ckpt_<upto>.pt, experiments.measures.summarise); both runners now "
                   "write the service's checkpoints, on a clock (service.checkpoint_every_s), none at an episode")
def test_the_first_episodes_of_a_run_are_measured_from_those_episodes_and_their_checkpoint(finished_run):
    run = Run("spread_cmcl_s0", "spread", "spread", "cmcl", None, 0, 12)
    whole = summarise(run, finished_run)
    first = summarise(replace(run, budget=8), finished_run, upto=8)
    rows = list(RunDirectory.open(finished_run).rows("episode"))
    assert whole["episodes"] == 12 and first["episodes"] == 8
    assert first["env_steps"] == rows[7]["env_steps"] < whole["env_steps"]
    assert first["updates"] == rows[7]["updates"] < whole["updates"]
    assert first["wall_s"] == rows[7]["elapsed_s"]
    coverage = np.array([r["coverage"] for r in rows])
    assert np.isclose(first["auc_coverage"], coverage[:8].mean())
    assert np.isclose(whole["auc_coverage"], coverage.mean())


def test_reading_past_a_checkpointed_prefix_names_the_run_and_the_missing_checkpoint(finished_run):
    with pytest.raises(ValueError, match=r"ckpt_00000006\.pt missing"):
        summarise(Run("x", "spread", "spread", "cmcl", None, 0, 6), finished_run, upto=6)


def test_a_shorter_ablation_gets_one_prefix_reference_per_seed_from_the_unchanged_cmcl_run():
    runs = [r for r in grid(["ablations"], [0, 1], ["cmcl"], budget=20_000)]
    short = [r for r in runs if r.budget < 20_000]
    assert {r.ablation for r in short} == {a for a, (_, _, b) in ABLATIONS.items() if b is not None}
    refs = prefix_reference_runs(runs + runs, 20_000)  # duplicates collapse
    budget = ABLATIONS["paper_schedule"][2]
    assert sorted(r.id for r in refs) == [f"reference_e{budget}_s0", f"reference_e{budget}_s1"]
    assert {r.source for r in refs} == {"spread_cmcl_s0", "spread_cmcl_s1"}
    assert prefix_reference_runs(runs, budget) == []  # a grid at that budget needs no prefix


def test_curriculum_grid_interleaves_arms_by_seed_and_only_the_controls_differ():
    runs = grid(["curriculum"], [0, 1], [])
    arms = ["maddpg", "per", "acl", "cmcl", "cmcl_permuted", "cmcl_anti"]
    assert [r.id for r in runs] == [f"curriculum_{a}_s{s}" for s in (0, 1) for a in arms]
    sets = {r.arm: r.sets for r in runs if r.seed == 0}
    assert sets["cmcl_permuted"] == ("teams.agent.priority.difficulty_transform=permuted",)
    assert sets["cmcl_anti"] == ("teams.agent.priority.difficulty_transform=reversed",)
    assert all(sets[a] == () for a in arms[:4])  # the shared defaults: nothing set
    hard = {r.arm: r for r in grid(["curriculum_hard"], [0], [])}
    assert hard["per"].config == "spread_hard.toml" and "teams.agent.algorithm=per" in hard["per"].sets
    assert hard["cmcl_anti"].sets == ("teams.agent.algorithm=cmcl",
                                          "teams.agent.priority.difficulty_transform=reversed")


def test_the_predator_prey_curriculum_grid_trains_each_arm_as_predators_against_maddpg_prey():
    tag = {r.arm: r for r in grid(["curriculum_tag"], [3], [])}
    assert list(tag) == ["maddpg", "per", "acl", "cmcl", "cmcl_permuted", "cmcl_anti"]
    assert all(r.task == "tag" and r.prey_algorithm == "maddpg" and r.seed == 3 for r in tag.values())
    assert tag["per"].config == "tag_per.toml" and tag["per"].sets == ()
    assert tag["cmcl_permuted"].config == "tag_cmcl.toml"
    # the predators' control (the old global key's only effect there: MADDPG prey sample uniformly either way)
    assert tag["cmcl_permuted"].sets == ("teams.predator.priority.difficulty_transform=permuted",)
    assert tag["cmcl_anti"].id == "curriculum_tag_cmcl_anti_s3"


def test_the_settings_grids_run_cmcl_on_the_harder_task_with_the_stride_or_the_curiosity_weight_changed():
    from cmcl.config import load_config

    runs = grid(["curriculum_stride"], [0, 1], [])
    assert [r.id for r in runs] == [f"curriculum_stride_cmcl_stride_{k}_s{s}" for s in (0, 1) for k in ("x2", "half")]
    assert all(r.config == "spread_hard.toml" and r.algorithm == "cmcl" and r.task == "spread" for r in runs)
    default = load_config(ROOT / "configs" / "spread_hard.toml").curriculum_stride()
    for r in runs[:2]:  # the strides against the derived default of the 20,000-episode budget
        stride = float(r.sets[0].split("=")[1])
        assert stride / default == {"cmcl_stride_x2": 2.0, "cmcl_stride_half": 0.5}[r.arm]
    (eta,) = grid(["curriculum_eta"], [3], [])  # one setting changed: the curiosity weight
    assert eta.id == "curriculum_eta_cmcl_eta1_s3" and eta.config == "spread_hard.toml"
    assert eta.sets == ("teams.agent.eta=1.0",)
    assert load_config(ROOT / "configs" / "spread_hard.toml").teams["agent"].eta == 0.5  # the default it doubles


def test_a_predator_prey_summary_has_the_area_under_the_win_curve_and_the_censored_times(tmp_path):
    path = tmp_path / "curriculum_tag_cmcl_s0"
    config = make_tiny_config("cmcl", "tag", service=True, sections=ONE_UPDATE_PER_STEP)
    train_tiny(config, path)
    run = grid(["curriculum_tag"], [0], [])[3]
    s = summarise(replace(run, budget=config.run.episodes), path)
    wins = [r["predator_win"] for r in RunDirectory.open(path).rows("episode")]
    assert s["auc_predator_win"] == pytest.approx(np.mean(wins))
    assert s["episodes_to_win_90"] is None  # fewer episodes than the moving average's window: never reached
    assert 0 <= s["win_vs_random_prey"] <= 1 and s["sampling_curve"]["episode"]


def test_a_summary_holds_the_sampling_distribution_over_training(finished_run):
    s = summarise(Run("spread_cmcl_s0", "spread", "spread", "cmcl", None, 0, 12), finished_run)
    curve = s["sampling_curve"]
    assert len(curve["episode"]) == len(curve["ess"]) >= 1
    assert all(0 < e <= 1 for e in curve["ess"]) and s["ess_mean"] == pytest.approx(np.mean(curve["ess"]), abs=1e-4)
    assert 0 <= s["reward_rows_buffer_mean"] <= 1


def test_a_summary_starts_with_the_fields_the_committed_summaries_have(finished_run):
    """New summaries keep the keys the report reads in the committed ones (lab/results/*/summaries)."""
    run = grid(["curriculum"], [0], [])[3]
    s = summarise(run, finished_run)
    assert list(s)[:7] == ["id", "grid", "task", "algorithm", "prey_algorithm", "seed", "budget"]
    assert s["arm"] == "cmcl" and s["config"] == "spread_cmcl.toml" and "sets" not in s  # none set
    ref = prefix_reference_runs(grid(["ablations"], [0], ["cmcl"]), 20_000)[0]
    assert ref.record()["ablation"] is None and ref.record()["source"] == "spread_cmcl_s0"


def test_every_grid_has_a_results_folder_and_the_time_to_solve_grids_stop_early():
    assert set(GRIDS) == {"spread", "tag", "winrate", "ablations", "curriculum", "curriculum_hard", "curriculum_tag",
                          "curriculum_stride", "curriculum_eta", "screen", "confirm", "make_run",
                          "schedule", "algorithms", "own_envs", "scale", "sparse_calibration", "sparse_recalibration",
                          "sparse_screen", "sparse_scale", "sparse_confirm"}
    schedule = grid(["schedule"], [0])
    assert len(schedule) == 8 and all(r.stop_coverage == 0.95 and r.max_seconds == 900 for r in schedule)
    assert {r.mode for r in grid(["algorithms"], [0])} == {"inline", "service"}
    scale = grid(["scale"], [0])
    assert [r.arm for r in scale] == ["n8_per_agent", "n8_entity", "n8_entity_stages", "n8_entity_stages_progress",
                                      "n4_entity", "n4_entity_stages", "n16_per_agent", "n16_entity",
                                      "n16_entity_long"]
    assert scale[0].budget == 20_000 and "env.num_agents=8" in scale[0].sets and scale[0].algorithm == "maddpg"
    assert "maddpg.networks=entity" in scale[1].sets and not scale[1].stages
    assert scale[2].stages == scale[3].stages == (2, 4, 8) and "run.stop_progress=0.05" in scale[3].sets
    by_arm = {r.arm: r for r in grid(["scale"], [0], budget=123)}
    assert by_arm["n8_per_agent"].budget == 123  # a cell without its own budget takes the grid's
    assert by_arm["n16_entity"].budget == by_arm["n16_per_agent"].budget == 3_040  # equal episodes at N = 16
    assert "run.init_from=" in by_arm["n16_entity"].sets  # from scratch: the preset's warm start cleared
    assert by_arm["n4_entity_stages"].stages == (2, 4) and by_arm["n4_entity"].config == "spread_n8.toml"
    with pytest.raises(ValueError, match="unknown \\['nope'\\]"):
        grid(["nope"], [0])


# out of the default run (its 10-minute budget): trains a real own-env run
@pytest.mark.extended
def test_an_own_env_run_trains_from_its_settings_and_is_measured_per_team_against_random(tmp_path):
    """The own_envs grid's simple_tag run: no config file, the env's settings; held-out return per team, the random
    policy's on the same worlds and each team against random opponents."""
    from cmcl.config import load_config
    from experiments.own_envs import OWN_ENVS
    from experiments.runner import command
    from tests.tiny import tiny_overrides

    runs = grid(["own_envs"], [0, 1])
    assert len(runs) == 2 * 2 * len(OWN_ENVS) and {r.seed for r in runs[:8]} == {0}
    run = next(r for r in runs if r.env == "tag" and r.mode == "service")
    path = tmp_path / run.id
    argv = command(run, path)
    assert "--config" not in argv and argv[2:6] == ["cmcl", "train", "--runner", "service"]
    assert f"env.factory={OWN_ENVS['tag'].factory}" in argv and "teams.adversary.algorithm=maddpg" in argv
    config = load_config(None, [*run.sets, *tiny_overrides(service=True), "run.episodes=8", f"run.dir={path}"])
    train_tiny(config, path)
    summary = summarise(replace(run, budget=8), path)
    assert summary["env"] == "tag" and summary["mode"] == "service" and summary["episodes"] == 8
    teams = {"adversary", "agent"}
    assert set(summary["held_out_return"]) == set(summary["random_return"]) == teams
    assert set(summary["vs_random_others_return"]) == teams
    assert summary["random_return"] != summary["held_out_return"]


def test_the_command_line_filters_curriculum_arms_with_arms_and_scale_cells_with_cells(tmp_path):
    """`--arms` names curriculum arms and `--cells` scale cells; neither filters the other grid's runs away."""
    scale = selected_runs(build_parser().parse_args(["run", "scale", "--seeds", "0", "1", "--arms", "cmcl"]))
    assert [r.id for r in scale][:2] == ["scale_n8_per_agent_s0", "scale_n8_entity_s0"] and len(scale) == 18
    cells = selected_runs(build_parser().parse_args(["run", "scale", "--seeds", "0", "1", "--cells", "n16_entity"]))
    assert [r.id for r in cells] == ["scale_n16_entity_s0", "scale_n16_entity_s1"]
    with pytest.raises(SystemExit):  # argparse: an unknown cell is refused, naming the choices
        build_parser().parse_args(["run", "scale", "--cells", "n32_entity"])
    some = selected_runs(build_parser().parse_args(["run", "curriculum", "--seeds", "0", "--arms", "cmcl"]))
    assert [r.id for r in some] == ["curriculum_cmcl_s0"]
    # the screen's arms, as a later commit's worktree runs an arm added to the protocol (laber)
    screen = selected_runs(build_parser().parse_args(["run", "screen", "--seeds", "100", "--arms", "laber", "--out",
                                                      str(tmp_path)]))
    assert [r.id for r in screen] == ["screen_laber_s100"]
    assert len(selected_runs(build_parser().parse_args(["run", "screen", "--seeds", "100", "--out",
                                                        str(tmp_path)]))) == 10


def test_an_agent_count_curriculum_run_is_trained_by_the_stages_command(tmp_path):
    """A run with stages: `python -m cmcl stages` with its agent counts and budgets, no --overwrite (the stages
    resume by themselves), the run folder as the curriculum's root; its record names the stages."""
    from experiments.run_spec import Run
    from experiments.runner import command

    run = Run("scale_x_s0", "scale", "spread", "maddpg", None, 0, 500, arm="x", config="spread_maddpg.toml",
              stages=(2, 4), stage_episodes=(100, 400))
    argv = command(run, tmp_path / "root")
    assert argv[1:4] == ["-m", "cmcl", "stages"] and "--overwrite" not in argv
    assert argv[argv.index("--agents") + 1:argv.index("--agents") + 3] == ["2", "4"]
    assert argv[argv.index("--stage-episodes") + 1:argv.index("--stage-episodes") + 3] == ["100", "400"]
    assert f"run.dir={tmp_path / 'root'}" in argv
    assert run.record()["stages"] == [2, 4] and run.record()["stage_episodes"] == [100, 400]


def test_the_screen_runs_each_candidate_rule_on_the_harder_task_with_one_override_more_than_its_rule():
    from cmcl.replay.registry import REGISTRY
    from experiments.screen_arms import ROUND_ONE_SEEDS, SCREEN_ARMS, SCREEN_REFERENCES

    runs = grid(["screen"], list(ROUND_ONE_SEEDS))  # round one: every arm
    assert [r.seed for r in runs[:len(SCREEN_ARMS)]] == [100] * len(SCREEN_ARMS)  # seed outermost
    assert {r.config for r in runs} == {"spread_hard.toml"} and set(SCREEN_REFERENCES) < set(SCREEN_ARMS)
    for r in runs:
        assert r.algorithm in REGISTRY and f"teams.agent.algorithm={r.algorithm}" in r.sets
        assert len(r.sets) <= 2  # the rule and at most one more override


def test_the_make_run_grid_runs_the_makefiles_command():
    """The grid's run is `make run`'s: the service, its config file (whose algorithm names the run), stop at MA 0.9
    or after 300 s."""
    import re
    import tomllib

    from experiments.grids import MAKE_RUN, MAKE_RUN_EPISODES
    from experiments.run_spec import ROOT
    from experiments.runner import command

    recipe = re.search(r"^run: install\n((?:\t.*\n)+)", (ROOT / "Makefile").read_text(), re.M).group(1)
    run = grid(["make_run"], [3])[0]
    config = f"configs/{MAKE_RUN['config']}"
    cmd = " ".join(command(run, Path("/nonexistent/run")))
    assert "cmcl train --runner service" in cmd and config in cmd and "--runner service" in recipe
    for flag in ("run.stop_coverage=0.9", "run.max_seconds=300", f"--config {config}", "run.episodes=$(RUN_EPISODES)"):
        assert flag in recipe
    episodes = re.search(r"^RUN_EPISODES \?= (\d+)$", (ROOT / "Makefile").read_text(), re.M).group(1)
    assert int(episodes) == MAKE_RUN_EPISODES and f"run.episodes={episodes}" in cmd
    trains = tomllib.loads((ROOT / config).read_text())["teams"]["agent"]["algorithm"]
    assert run.algorithm == trains and run.id == f"make_run_{trains}_s3"
    assert "run.stop_coverage=0.9" in cmd and "run.max_seconds=300.0" in cmd and "run.seed=3" in cmd


def test_tasks_selects_the_sparse_grids_runs_by_task_and_leaves_other_grids_whole():
    args = build_parser().parse_args(["run", "sparse_calibration", "make_run", "--arms", "maddpg", "--tasks",
                                      "vacl_n4", "--seeds", "0", "1", "--out", "x"])
    runs = selected_runs(args)
    sparse = [r for r in runs if r.grid == "sparse_calibration"]
    assert [r.id for r in sparse] == ["sparse_calibration_vacl_n4_maddpg_s0", "sparse_calibration_vacl_n4_maddpg_s1"]
    assert len([r for r in runs if r.grid == "make_run"]) == 2

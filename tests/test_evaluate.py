"""Evaluation of checkpoints: statistics in the batched twin, GIFs from the PettingZoo env, CLI errors."""

import json

import pytest
from PIL import Image

from cmcl.config import load_config, preset
from cmcl.envs.examples.reach import Reach
from cmcl.run.evaluate import evaluate_policy, gif_line, main, render_gif
from cmcl.system import agent_layout, build_maddpg, make_batched_env


@pytest.mark.parametrize("task", ["spread", "tag"])
def test_random_and_policy_statistics(task):
    config = preset("cmcl", task)
    rand = evaluate_policy(config, None, episodes=40, seed=1)
    assert rand["episodes"] == 40 and rand["policy"] == "random"
    maddpg = build_maddpg(config, agent_layout(config, make_batched_env(config, num_envs=1)), seed=0)
    pol = evaluate_policy(config, maddpg, episodes=40, seed=1)
    key = "coverage" if task == "spread" else "predator_win"
    for result in (rand, pol):
        assert 0.0 <= result[key] <= 1.0
        assert set(result["reward"]) == ({"agent"} if task == "spread" else {"predator", "prey"})
    assert evaluate_policy(config, maddpg, episodes=40, seed=1) == pol  # deterministic for a seed


def test_a_saturated_policy_is_measured_and_warned_about_and_a_fresh_one_is_not():
    import torch

    from cmcl.run.evaluate import saturation_line

    config = preset("maddpg", "spread")
    maddpg = build_maddpg(config, agent_layout(config, make_batched_env(config, num_envs=1)), seed=0)
    fresh = evaluate_policy(config, maddpg, episodes=20, seed=1)
    assert 0.0 <= fresh["saturated_actions"] < 0.5 and saturation_line(fresh) == ""
    with torch.no_grad():
        maddpg.actor.layers[-1].bias.fill_(12.0)  # every pre-tanh output far past the bound
    pushed = evaluate_policy(config, maddpg, episodes=20, seed=1)
    assert pushed["saturated_actions"] == 1.0 and saturation_line(pushed).startswith("warning: 100% of the trained")
    assert "saturated_actions" not in evaluate_policy(config, None, episodes=20, seed=1)  # random: not a policy's


@pytest.mark.parametrize("task", ["spread", "tag"])
def test_gif_has_one_frame_per_step(task, tmp_path):
    config = preset("maddpg", task)
    maddpg = build_maddpg(config, agent_layout(config, make_batched_env(config, num_envs=1)), seed=0)
    path = render_gif(config, maddpg, tmp_path / "episode.gif")
    with Image.open(path) as gif:
        assert gif.size[0] > 100 and gif.n_frames >= 2


def test_cli_on_a_folder_without_a_run(tmp_path, capsys):
    assert main([str(tmp_path)]) == 2
    assert "not a run directory" in capsys.readouterr().err


def test_cli_evaluates_a_trained_smoke_run(tmp_path, capsys):
    from cmcl.__main__ import main as cmcl

    run = tmp_path / "run"
    assert cmcl(["train", "--runner", "inline", "--config", "configs/smoke.toml", "--set", f"run.dir={run}",
                 "--set", "run.episodes=8", "--set", "maddpg.warmup=64", "--set", "maddpg.batch_size=16",
                 "--quiet"]) == 0
    capsys.readouterr()
    assert main([str(run), "--episodes", "8", "--gif", str(tmp_path / "e.gif")]) == 0
    text = capsys.readouterr().out
    result = json.loads(text[: text.index("gif:")])
    assert result["policy"] == "trained" and result["checkpoint"].endswith("checkpoints/service/learner-000001.pt")
    assert (tmp_path / "e.gif").stat().st_size > 0


def test_a_team_can_act_at_random_against_the_policy():
    config = preset("cmcl", "tag")
    maddpg = build_maddpg(config, agent_layout(config, make_batched_env(config, num_envs=1)), seed=0)
    both = evaluate_policy(config, maddpg, episodes=200, seed=3)
    random_prey = evaluate_policy(config, maddpg, episodes=200, seed=3, random_teams=("prey",))
    everyone_random = evaluate_policy(config, maddpg, episodes=200, seed=3, random_teams=("predator", "prey"))
    assert everyone_random == {**evaluate_policy(config, None, episodes=200, seed=3), "policy": "trained"}
    assert random_prey != both  # the prey's actions changed, the worlds did not
    with pytest.raises(ValueError, match="'wolves', not a team"):
        evaluate_policy(config, maddpg, episodes=2, random_teams=("wolves",))


class Unrenderable(Reach):
    """The example environment, drawn by a renderer that is missing here (as MuJoCo's OpenGL on a headless host)."""

    def render(self):
        raise RuntimeError("an OpenGL platform library has not been loaded into this process")


def unrenderable(max_cycles=25, render_mode=None):
    return Unrenderable(max_cycles, render_mode)


def test_an_environment_that_cannot_render_gets_no_gif_and_a_reason_not_a_failure(tmp_path):
    config = load_config(None, ["env.factory=tests.test_evaluate:unrenderable", "env.episode_length=25"])
    line = gif_line(config, None, tmp_path / "eval.gif")
    assert line.startswith("gif: none") and "OpenGL platform library" in line, line
    assert not (tmp_path / "eval.gif").exists()
    assert gif_line(load_config(None, ["env.factory=cmcl.envs.examples.reach:parallel_env",
                                       "env.episode_length=25"]), None, tmp_path / "ok.gif") == \
        f"gif: {tmp_path / 'ok.gif'}"


def test_a_gif_path_that_cannot_be_written_is_said_not_written_not_blamed_on_the_environment(tmp_path):
    """Before (found by hand 2026-12-06): `evaluate --gif /proc/x.gif` said "the environment could not render here
    (FileNotFoundError: ...)"; under a file it then said the OS's "File exists"."""
    config = load_config(None, ["env.factory=cmcl.envs.examples.reach:parallel_env", "env.episode_length=25"])
    blocked = tmp_path / "a file"
    blocked.write_text("")
    assert gif_line(config, None, blocked / "eval.gif") == \
        f"gif: not written (cannot write {blocked / 'eval.gif'}: a folder on its path is a file)"
    assert gif_line(config, None, blocked / "deeper" / "eval.gif") == \
        f"gif: not written (cannot write {blocked / 'deeper' / 'eval.gif'}: a folder on its path is a file)"

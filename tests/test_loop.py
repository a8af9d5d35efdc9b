"""The inline runner (`--runner inline`: the service's roles under its supervisor, in one process,
services.launch.train_in_process): a short run of every algorithm preset, checkpoints and resume, the CLI."""

import functools
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from cmcl.__main__ import main as cmcl
from cmcl.config import config_from_dict
from cmcl.run.rundir import RunDirectory
from cmcl.run.runlock import LOCK_NAME
from services.launch import train_in_process
from services.runtime.placement import create_roles

# The tests' runs on top of the shared tiny service config (tests/conftest.py, tests/tiny.py: calls of 8 learner
# updates, 3 teacher folds): one update per env step after the warm-up.
INLINE_SECTIONS = {"maddpg": {"update_every": 1}}


@pytest.fixture
def tiny_config(tiny_config):
    return functools.partial(tiny_config, service=True, sections=INLINE_SECTIONS)


def train(config):
    """Train `config` in one process in a new run directory config.run.dir: (summary, roles)."""
    return train_in_process(config, RunDirectory.create(config.run.dir, config))


def main(argv):
    """`python -m cmcl train --runner inline ARGV` (or `resume ...` when ARGV starts with it)."""
    return cmcl(argv if argv[0] == "resume" else ["train", "--runner", "inline", *argv])


@pytest.mark.parametrize("algorithm", ["maddpg", "per", "acl", "cmcl"])
def test_each_algorithm_runs_and_learns_from_its_own_priorities(algorithm, tmp_path, tiny_config):
    config = tiny_config(algorithm, dir=str(tmp_path / algorithm))
    summary, roles = train(config)
    assert summary["episodes"] == 12 and summary["env_steps"] == 12 * 30
    # one update owed per env step from the batched step that completed the 96-transition warm-up on; the learner
    # is handed them in calls of service.updates_per_call (the last call may run ahead of what is owed)
    owed, per_call = summary["env_steps"] - (96 - config.env.num_envs), config.service.updates_per_call
    assert owed <= summary["updates"] < owed + per_call
    assert summary["lambda"] > config.curriculum.lam0  # λ advanced after warm-up
    replay = roles.replay.replay
    valid = replay.valid_slots()
    scored = replay.storage.scored
    if algorithm in ("acl", "cmcl"):
        assert scored["difficulty"][valid].all(), "every stored row carries a teacher difficulty"
        probs = replay.probabilities(0, valid)
        assert probs.std() > 0, "priorities are not uniform"
    else:
        assert not scored["difficulty"].any()
    assert scored["curiosity"][valid].all() == (algorithm == "cmcl")
    if algorithm == "per":
        assert scored["td_abs"][valid].any() and replay.sampling[0].max_priority > 1e-3
    rows = list(RunDirectory.open(config.run.dir).rows("episode"))
    assert [r["episodes"] for r in rows] == list(range(1, 13))
    assert all(0.0 <= r["coverage"] <= 1.0 for r in rows)
    service = RunDirectory.open(config.run.dir).service_dir  # every role's verified checkpoint, at the end
    roles_saved = {"learner", "replay", *(["teacher"] if algorithm in ("acl", "cmcl") else []),
                   *(["icm"] if algorithm == "cmcl" else [])}
    saved = {p.name.split(".")[0].split("_")[0] for p in service.glob("*.manifest.json")}  # learner, teacher_0-1-2
    saved |= {"replay"} if (service / "replay" / "manifest.json").is_file() else set()
    assert saved == roles_saved


def test_eight_agents_with_shared_networks_run_and_resume_their_weights(tmp_path, tiny_config):
    """Scale: N = 8 navigation with one shared actor and critic and one teacher per fold; the
    learner's and the teachers' weights change, every row is scored, and a checkpoint restores them."""
    data = tiny_config("cmcl", dir=str(tmp_path / "n8")).to_dict()
    data["env"]["num_agents"], data["maddpg"]["networks"] = 8, "shared"
    data["teachers"]["networks"] = "shared"
    config = config_from_dict(data)
    fresh = create_roles(config, RunDirectory.create(tmp_path / "fresh", config), in_process=True)
    before = {k: v.clone() for k, v in fresh.learner.maddpg.actor.state_dict().items()}
    teachers_before = {k: v.clone() for k, v in fresh.teachers[0].teachers.net.state_dict().items()}
    summary, roles = train(config)
    maddpg, teachers = roles.learner.maddpg, roles.teachers[0].teachers  # one process: one stacked ensemble
    assert summary["episodes"] == 12 and maddpg.actor.layers[1].weight.shape[0] == 1
    folds = config.teachers.num_folds
    assert teachers.net.layers[1].weight.shape[0] == folds, "one teacher network per fold"
    assert any(not torch.equal(teachers_before[k], v) for k, v in teachers.net.state_dict().items())
    valid = roles.replay.replay.valid_slots()
    assert roles.replay.replay.storage.scored["difficulty"][valid].all()
    after = maddpg.actor.state_dict()
    assert maddpg.actor.layers[0].bias.shape == (8, 32), "each agent keeps its own first-layer bias"
    assert any(not torch.equal(before[k], after[k]) for k in before)
    run_dir = RunDirectory.open(config.run.dir)
    resumed = create_roles(run_dir.config(()), run_dir, in_process=True)
    for k, v in after.items():
        assert torch.equal(resumed.learner.maddpg.actor.state_dict()[k], v), k
    for k, v in teachers.net.state_dict().items():
        assert torch.equal(resumed.teachers[0].teachers.net.state_dict()[k], v), k


def test_predator_prey_pits_cmcl_predators_against_per_prey(tmp_path, tiny_config):
    config = tiny_config("cmcl", task="tag", opponent="per", dir=str(tmp_path / "tag"), episodes=8)
    summary, roles = train(config)
    layout = roles.learner.layout
    predators, prey = layout.teams["predator"], layout.teams["prey"]
    assert layout.teacher_agents.tolist() == predators
    assert [layout.algorithms[a] for a in prey] == ["per", "per"]
    replay = roles.replay.replay
    valid = replay.valid_slots()
    assert replay.storage.scored["difficulty"][valid][:, predators].all()
    assert not replay.storage.scored["difficulty"][:, prey].any()
    assert set(summary["window"]["reward"]) == {"predator", "prey"} and "predator_win" in summary["window"]


def test_resume_restores_what_the_run_saved_and_continues_it(tmp_path, tiny_config):
    """A run stopped at episode 8: its roles, built again from the run directory, hold the saved weights, replay
    rows and counters; resumed to 12 episodes it counts as a run of 12 straight would, its episode rows numbered on.
    (Not to the bit: a resumed rollout worker starts new worlds, services/roles/rollout.py.)"""
    # an explicit λ stride: the default one depends on run.episodes, which differs between the two runs
    straight = tiny_config("cmcl", dir=str(tmp_path / "straight"), episodes=12, sections={
        **INLINE_SECTIONS, "curriculum": {"stride": 1e-3}})
    full_summary, _ = train(straight)
    first = config_from_dict({**straight.to_dict(), "run": {**straight.to_dict()["run"], "episodes": 8,
                                                             "dir": str(tmp_path / "split")}})
    part_summary, part = train(first)
    run_dir = RunDirectory.open(first.run.dir)
    config = run_dir.config(("run.episodes=12",))
    restored = create_roles(config, run_dir, in_process=True)
    assert restored.replay.counters == part.replay.counters and restored.replay.resumed
    np.testing.assert_array_equal(restored.replay.replay.storage.obs, part.replay.replay.storage.obs)
    assert restored.replay.schedule.lam == part.replay.schedule.lam
    for key, value in part.learner.maddpg.state_dict()["actor"].items():
        torch.testing.assert_close(restored.learner.maddpg.state_dict()["actor"][key], value, rtol=0, atol=0)
    for key, value in part.teachers[0].teachers.net.state_dict().items():
        torch.testing.assert_close(restored.teachers[0].teachers.net.state_dict()[key], value, rtol=0, atol=0)
    resumed_summary, resumed = train_in_process(config, run_dir, resume=True)
    for key in ("episodes", "env_steps", "updates"):
        assert resumed_summary[key] == full_summary[key], key
    assert resumed.replay.counters["updates"] > part_summary["updates"] and resumed.replay.replay.size == 360
    assert [r["episodes"] for r in run_dir.rows("episode")] == list(range(1, 13))


def test_cli_smoke_and_resume(tmp_path, capsys, tiny_config_file):
    run = tmp_path / "cli"
    args = ["--config", str(tiny_config_file("cmcl", dir=str(run), episodes=8))]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "ep 8/8" in out and "λ" in out and (run / "learning_curve.png").stat().st_size > 0
    assert main(args) == 2  # refuses to overwrite a run
    assert "already holds a run" in capsys.readouterr().err
    assert main(["resume", str(run), "--set", "run.episodes=12"]) == 0
    assert f"resuming {run} from checkpoints/service/learner-" in capsys.readouterr().out
    episodes = [r["episodes"] for r in RunDirectory.open(run).rows("episode")]
    assert episodes == list(range(1, 13))


def test_cli_rejects_bad_config(capsys):
    assert main(["--config", "configs/spread_cmcl.toml", "--set", "maddpg.gamma=7"]) == 2
    assert "maddpg.gamma" in capsys.readouterr().err


@pytest.mark.parametrize("changed", ["teachers.networks=shared", "maddpg.networks=shared",
                                     "teachers.num_folds=2", "maddpg.networks=entity"])
def test_resuming_under_other_network_settings_names_them_and_keeps_the_run(tmp_path, capsys, changed,
                                                                             tiny_config):
    config = tiny_config("cmcl", dir=str(tmp_path / "run"), episodes=4, sections={})
    train(config)
    stored = {p: p.read_bytes() for p in Path(config.run.dir).rglob("*") if p.is_file()}
    assert main(["resume", config.run.dir, "--set", changed, "--set", "run.episodes=8"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    # named before anything starts (cmcl.run.resume_shapes), the setting alone (not run.episodes), with both shapes
    assert err.startswith(f"error: resume --set {changed}: the run's checkpoints hold other shapes ("), err
    if "=shared" in changed:
        assert f"({changed.split('.')[0]} " in err and " in them, (" in err and " with these settings)" in err
    elif "networks=entity" in changed:  # other tensors altogether: one of the stored ones, absent under the setting
        assert "(maddpg actor.layers.0.weight: (" in err and "in them, none with these settings)" in err
    else:
        assert "(teachers.num_folds: 3 in them, 2 with these settings)" in err
    # run.lock names the last holder (this refused resume): the one file a refusal may write
    after = {p: p.read_bytes() for p in Path(config.run.dir).rglob("*") if p.is_file() and p.name != LOCK_NAME}
    assert after == stored


def test_cmcl_at_eta_zero_trains_exactly_as_acl(tmp_path, tiny_config):
    """CI = KP + η·CP (eq. 14) at η = 0 is ACL's KP priority: CMCL then builds no ICM (nothing reads curiosity)
    and must train exactly as ACL, to the bit (the ablation grid found the same over 20,000 episodes on 5 seeds).
    Any CMCL-only setting or random stream that leaked into the rest of the run would break this."""
    data = tiny_config("cmcl", dir=str(tmp_path / "cmcl"), episodes=8).to_dict()
    data["teams"]["agent"]["eta"] = 0.0
    cmcl_config = config_from_dict(data)
    acl = tiny_config("acl", dir=str(tmp_path / "acl"), episodes=8)
    (cmcl_summary, ours), (acl_summary, theirs) = train(cmcl_config), train(acl)
    assert ours.icm is None and cmcl_summary["updates"] == acl_summary["updates"]
    steps = [r.replay.teacher_steps for r in (ours, theirs)]
    assert steps[0] == steps[1] and min(steps[0]) > 0
    for mine, other in zip(ours.learner.maddpg.actor.parameters(), theirs.learner.maddpg.actor.parameters(),
                           strict=True):
        assert torch.equal(mine, other)
    rows = [[(r["coverage"], r["reward"]) for r in RunDirectory.open(c.run.dir).rows("episode")]
            for c in (cmcl_config, acl)]
    assert rows[0] == rows[1]
    np.testing.assert_array_equal(ours.replay.replay.storage.obs, theirs.replay.replay.storage.obs)


def test_a_run_ended_by_its_time_budget_resumes_for_that_budget_again_and_its_clock_goes_on(tmp_path, tiny_config):
    """run.max_seconds is each command's budget (as `make resume`'s "5 more minutes"): a run that spent it trains
    further when resumed; elapsed_s, in the rows and the summary, counts every segment, segment_s this one."""
    config = tiny_config("maddpg", dir=str(tmp_path / "budget"), episodes=100_000, max_seconds=0.5)
    first, _ = train(config)
    done = first["episodes"]
    assert 0 < done < 100_000 and first["elapsed_s"] >= 0.5 and first["segment_s"] == pytest.approx(
        first["elapsed_s"])
    run_dir = RunDirectory.open(config.run.dir)
    # the clock as the last checkpoint saved it (the summary's is read a few ms after that checkpoint)
    saved = json.loads(run_dir.service_paths()["supervisor"].read_text())["elapsed_s"]
    assert 0.5 <= saved <= first["elapsed_s"]
    resumed, _ = train_in_process(run_dir.config(), run_dir, resume=True)
    # (how many episodes it adds in 0.5 s depends on the machine's load: not asserted)
    assert resumed["segment_s"] >= 0.5, "the resumed run trained for its own budget (it stopped after one step)"
    assert resumed["elapsed_s"] >= saved + resumed["segment_s"] - 1e-6
    last = list(run_dir.rows("progress"))[-1]  # a progress row is logged at every end
    assert last["segment_s"] >= 0.5 and last["elapsed_s"] >= saved + last["segment_s"] - 1e-6, last
    clock = [r["elapsed_s"] for r in run_dir.rows("episode")]
    assert clock == sorted(clock), "the clock goes on across the resume"

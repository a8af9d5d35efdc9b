"""The inline Algorithm 1 loop: a short run of every algorithm preset, checkpoints, exact resume, CLI."""

import functools
from pathlib import Path

import numpy as np
import pytest
import torch

from cmcl.config import config_from_dict
from cmcl.io.checkpoint_files import load_checkpoint
from cmcl.io.rundir import RunDirectory
from cmcl.io.runlock import LOCK_NAME
from cmcl.loop import InlineLoop
from cmcl.loop.__main__ import main

# The inline loop's tests on top of the shared tiny config (tests/conftest.py): one update per env step after the
# warm-up, a checkpoint and a log row every 4 episodes.
INLINE_SECTIONS = {"maddpg": {"update_every": 1}, "teachers": {"rescore_rows_per_update": 64},
                   "run": {"log_every": 4, "checkpoint_every": 4}}


@pytest.fixture
def tiny_config(tiny_config):
    return functools.partial(tiny_config, sections=INLINE_SECTIONS)


@pytest.mark.parametrize("algorithm", ["maddpg", "per", "acl", "cmcl"])
def test_each_algorithm_runs_and_learns_from_its_own_priorities(algorithm, tmp_path, tiny_config):
    config = tiny_config(algorithm, dir=str(tmp_path / algorithm))
    loop = InlineLoop(config, RunDirectory.create(config.run.dir, config), progress=None)
    row = loop.run()
    c = loop.counters
    assert c["episodes"] == 12 and c["env_steps"] == 12 * 30
    # one update per env step from the batched step that completed the 96-transition warm-up on
    assert c["updates"] == c["env_steps"] - (96 - config.env.num_envs)
    assert row["lambda"] > config.curriculum.lam0  # λ advanced after warm-up
    storage = loop.replay.storage
    valid = loop.replay.valid_slots()
    scored = storage.scored
    if algorithm in ("acl", "cmcl"):
        assert scored["difficulty"][valid].all(), "every stored row carries a teacher difficulty"
        probs = loop.replay.probabilities(0, valid)
        assert probs.std() > 0, "priorities are not uniform"
    else:
        assert not scored["difficulty"].any()
    assert scored["curiosity"][valid].all() == (algorithm == "cmcl")
    if algorithm == "per":
        assert scored["td_abs"][valid].any() and loop.replay.sampling[0].max_priority > 1e-3
    rows = list(RunDirectory.open(config.run.dir).rows("episode"))
    assert [r["episodes"] for r in rows] == list(range(1, 13))
    assert all(0.0 <= r["coverage"] <= 1.0 for r in rows)
    assert len(list(Path(config.run.dir, "checkpoints").glob("ckpt_*.pt"))) == 3


def test_eight_agents_with_shared_networks_run_and_resume_their_weights(tmp_path, tiny_config):
    """Scale (issue 11): N = 8 navigation with one shared actor and critic and one teacher per fold; the
    learner's and the teachers' weights change, every row is scored, and a checkpoint restores them."""
    data = tiny_config("cmcl", dir=str(tmp_path / "n8")).to_dict()
    data["env"]["num_agents"], data["maddpg"]["share_parameters"] = 8, True
    data["teachers"]["share_parameters"] = True
    config = config_from_dict(data)
    loop = InlineLoop(config, RunDirectory.create(config.run.dir, config), progress=None)
    before = {k: v.clone() for k, v in loop.maddpg.actor.state_dict().items()}
    teachers_before = {k: v.clone() for k, v in loop.teachers.net.state_dict().items()}
    loop.run()
    assert loop.counters["episodes"] == 12 and loop.maddpg.actor.layers[1].weight.shape[0] == 1
    folds = config.teachers.num_folds
    assert loop.teachers.net.layers[1].weight.shape[0] == folds, "one teacher network per fold"
    assert any(not torch.equal(teachers_before[k], v) for k, v in loop.teachers.net.state_dict().items())
    valid = loop.replay.valid_slots()
    assert loop.replay.storage.scored["difficulty"][valid].all()
    after = loop.maddpg.actor.state_dict()
    assert loop.maddpg.actor.layers[0].bias.shape == (8, 32), "each agent keeps its own first-layer bias"
    assert any(not torch.equal(before[k], after[k]) for k in before)
    run_dir = RunDirectory.open(config.run.dir)
    resumed = InlineLoop(run_dir.config(()), run_dir, progress=None)
    resumed.restore(run_dir.latest_checkpoint())
    for k, v in after.items():
        assert torch.equal(resumed.maddpg.actor.state_dict()[k], v), k


def test_predator_prey_pits_cmcl_predators_against_per_prey(tmp_path, tiny_config):
    config = tiny_config("cmcl", task="tag", opponent="per", dir=str(tmp_path / "tag"), episodes=8)
    loop = InlineLoop(config, None, progress=None)
    loop.run()
    predators, prey = loop.layout.teams["predator"], loop.layout.teams["prey"]
    assert loop.layout.teacher_agents.tolist() == predators
    assert [loop.layout.algorithms[a] for a in prey] == ["per", "per"]
    valid = loop.replay.valid_slots()
    assert loop.replay.storage.scored["difficulty"][valid][:, predators].all()
    assert not loop.replay.storage.scored["difficulty"][:, prey].any()
    row = loop.progress_row(1.0, {"env_steps_per_s": 0.0, "updates_per_s": 0.0})
    assert set(row["window"]["reward"]) == {"predator", "prey"} and "predator_win" in row["window"]


def _final_weights(loop: InlineLoop) -> dict[str, torch.Tensor]:
    return {k: v.clone() for k, v in loop.maddpg.actor.state_dict().items()}


# the older checkpoint layout is extended (out of the default run's budget)
@pytest.mark.parametrize("older", [False, pytest.param(True, marks=pytest.mark.extended)],
                         ids=["checkpoint", "checkpoint_before_the_pacing_was_saved"])
def test_resume_continues_exactly_where_the_run_stopped(older, tmp_path, tiny_config):
    # an explicit λ stride: the default one depends on run.episodes, which differs between the two runs
    straight = tiny_config("cmcl", dir=str(tmp_path / "straight"), episodes=12, checkpoint_every=4)
    straight = config_from_dict({**straight.to_dict(), "curriculum": {"stride": 1e-3}})
    full = InlineLoop(straight, RunDirectory.create(straight.run.dir, straight), progress=None)
    full.run()

    first = config_from_dict({**straight.to_dict(), "run": {**straight.to_dict()["run"], "episodes": 8,
                                                             "dir": str(tmp_path / "split")}})
    part = InlineLoop(first, RunDirectory.create(first.run.dir, first), progress=None)
    part.run()
    run_dir = RunDirectory.open(first.run.dir)
    if older:  # its teacher / ICM step counts were in "counters", and it had no "pacing"
        state = load_checkpoint(run_dir.latest_checkpoint())
        pacing = state.pop("pacing")
        state["counters"].update(teacher_steps=pacing["teacher_limits"][0]["samples"],
                                 icm_steps=pacing["icm_limit"]["samples"])
        run_dir.save_checkpoint(state["counters"]["episodes"], state)
    resumed = InlineLoop(run_dir.config(("run.episodes=12",)), run_dir, progress=None)
    resumed.restore(run_dir.latest_checkpoint())
    assert resumed.counters["episodes"] == 8 and resumed.counters["updates"] == part.counters["updates"]
    resumed.run()
    assert resumed.counters == full.counters
    for key, value in _final_weights(full).items():
        torch.testing.assert_close(_final_weights(resumed)[key], value, rtol=0, atol=0)
    np.testing.assert_array_equal(resumed.replay.storage.obs, full.replay.storage.obs)


def test_cli_smoke_and_resume(tmp_path, capsys, tiny_config_file):
    run = tmp_path / "cli"
    args = ["--config", str(tiny_config_file("cmcl", dir=str(run), episodes=8))]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "ep 8/8" in out and "λ" in out and (run / "learning_curve.png").stat().st_size > 0
    assert main(args) == 2  # refuses to overwrite a run
    assert "already holds a run" in capsys.readouterr().err
    assert main(["--resume", str(run), "--set", "run.episodes=12"]) == 0
    assert "resumed from" in capsys.readouterr().out
    episodes = [r["episodes"] for r in RunDirectory.open(run).rows("episode")]
    assert episodes == list(range(1, 13))


def test_cli_rejects_bad_config(capsys):
    assert main(["--config", "configs/spread_cmcl.toml", "--set", "maddpg.gamma=7"]) == 2
    assert "maddpg.gamma" in capsys.readouterr().err


@pytest.mark.parametrize("changed", ["teachers.share_parameters=true", "maddpg.share_parameters=true",
                                     "teachers.num_folds=2", "maddpg.networks=entity"])
def test_resuming_under_other_network_settings_names_them_and_keeps_the_run(tmp_path, capsys, changed,
                                                                             tiny_config):
    config = tiny_config("cmcl", dir=str(tmp_path / "run"), episodes=4)
    InlineLoop(config, RunDirectory.create(config.run.dir, config), progress=None).run()
    stored = {p: p.read_bytes() for p in Path(config.run.dir).rglob("*") if p.is_file()}
    assert main(["--resume", config.run.dir, "--set", changed, "--set", "run.episodes=8"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    # named before anything starts (cmcl.resume_shapes), the setting alone (not run.episodes), with both shapes
    assert err.startswith(f"error: resume --set {changed}: the run's checkpoints hold other shapes ("), err
    if "share_parameters" in changed:
        assert f"({changed.split('.')[0]} " in err and " in them, (" in err and " with these settings)" in err
    elif "networks" in changed:  # other tensors altogether: one of the stored ones, absent under the setting
        assert "(maddpg actor.layers.0.weight: (" in err and "in them, none with these settings)" in err
    else:
        assert "(teachers.num_folds: 5 in them, 2 with these settings)" in err
    # run.lock names the last holder (this refused resume): the one file a refusal may write
    after = {p: p.read_bytes() for p in Path(config.run.dir).rglob("*") if p.is_file() and p.name != LOCK_NAME}
    assert after == stored


def test_cmcl_at_eta_zero_trains_exactly_as_acl(tmp_path, tiny_config):
    """CI = KP + η·CP (eq. 14) at η = 0 is ACL's KP priority: CMCL then builds no ICM (nothing reads curiosity)
    and must train exactly as ACL, to the bit (the ablation grid found the same over 20,000 episodes on 5 seeds).
    Any CMCL-only setting or random stream that leaked into the rest of the loop would break this."""
    data = tiny_config("cmcl", dir=str(tmp_path / "cmcl"), episodes=8).to_dict()
    data["teams"]["agent"]["eta"] = 0.0
    cmcl = config_from_dict(data)
    acl = tiny_config("acl", dir=str(tmp_path / "acl"), episodes=8)
    loops = [InlineLoop(c, RunDirectory.create(c.run.dir, c), progress=None) for c in (cmcl, acl)]
    for loop in loops:
        loop.run()
    assert loops[0].icm is None and loops[0].teachers.steps == loops[1].teachers.steps > 0
    for ours, theirs in zip(loops[0].maddpg.actor.parameters(), loops[1].maddpg.actor.parameters(), strict=True):
        assert torch.equal(ours, theirs)
    rows = [[(r["coverage"], r["reward"]) for r in RunDirectory.open(c.run.dir).rows("episode")] for c in (cmcl, acl)]
    assert rows[0] == rows[1]
    np.testing.assert_array_equal(loops[0].replay.storage.obs, loops[1].replay.storage.obs)


def test_a_run_killed_while_checkpointing_never_leaves_a_checkpoint_without_its_replay(tmp_path, tiny_config,
                                                                                       monkeypatch):
    """The replay snapshot is written first and the checkpoint last: a kill between the two writes (here: the
    replay write failing, as a SIGKILL would end it) leaves the previous whole checkpoint the newest one."""
    config = tiny_config("cmcl", dir=str(tmp_path / "run"), episodes=8, checkpoint_every=4)
    loop = InlineLoop(config, RunDirectory.create(config.run.dir, config), progress=None)
    loop.run()
    run_dir = RunDirectory.open(config.run.dir)
    assert list(run_dir.inline_checkpoints()) == [4, 8]

    def killed_while_writing(*args, **kwargs):
        raise KeyboardInterrupt("killed while writing the replay snapshot")

    monkeypatch.setattr("cmcl.loop.checkpoint.write_replay_snapshot", killed_while_writing)
    loop.counters["episodes"] = 12
    with pytest.raises(KeyboardInterrupt):
        loop.save_checkpoint()
    assert list(run_dir.inline_checkpoints()) == [4, 8]  # no checkpoint 12 without its replay
    resumed = InlineLoop(run_dir.config(()), run_dir, progress=None)
    resumed.restore(run_dir.latest_checkpoint())
    assert resumed.counters["episodes"] == 8


def test_a_run_ended_by_its_time_budget_resumes_for_that_budget_again_and_its_clock_goes_on(tmp_path, tiny_config):
    """run.max_seconds is each command's budget (as `make resume`'s "5 more minutes"): a run that spent it trains
    further when resumed; elapsed_s, in the rows and the summary's loop, counts every segment, segment_s this one."""
    config = tiny_config("maddpg", dir=str(tmp_path / "budget"), episodes=100_000, checkpoint_every=0)
    config = config_from_dict({**config.to_dict(), "run": {**config.to_dict()["run"], "max_seconds": 0.5}})
    first = InlineLoop(config, RunDirectory.create(config.run.dir, config), progress=None)
    first.run()
    done = first.counters["episodes"]
    assert 0 < done < 100_000 and first.elapsed_s >= 0.5 and first.segment_s == pytest.approx(first.elapsed_s)
    run_dir = RunDirectory.open(config.run.dir)
    resumed = InlineLoop(run_dir.config(), run_dir, progress=None)
    resumed.restore(run_dir.latest_checkpoint())
    resumed.run()  # (how many episodes it adds in 0.5 s depends on the machine's load: not asserted)
    assert resumed.segment_s >= 0.5, "the resumed run trained for its own budget (it stopped after one step)"
    assert resumed.elapsed_s >= first.elapsed_s + resumed.segment_s - 1e-6
    last = list(run_dir.rows("progress"))[-1]  # a progress row is logged at every end
    assert last["segment_s"] >= 0.5 and last["elapsed_s"] >= first.elapsed_s + last["segment_s"] - 1e-6, last
    clock = [r["elapsed_s"] for r in run_dir.rows("episode")]
    assert clock == sorted(clock), "the clock goes on across the resume"

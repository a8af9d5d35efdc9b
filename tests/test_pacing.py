"""cmcl/replay/pacing.py: one pacing for both runners, Algorithm 1's warm-up rule, and its state across versions."""

import dataclasses
import math

import numpy as np
import pytest

from cmcl.config import preset
from cmcl.replay.pacing import pacing_from_config


def _with(config, num_envs=None, **maddpg):
    """`config` with other maddpg settings (and env.num_envs)."""
    env = dataclasses.replace(config.env, num_envs=num_envs or config.env.num_envs)
    return dataclasses.replace(config, env=env, maddpg=dataclasses.replace(config.maddpg, **maddpg))


def test_pacing_from_config_builds_the_limiters_the_teams_need():
    cmcl = pacing_from_config(preset("cmcl"))
    assert len(cmcl.teachers) == preset("cmcl").teachers.num_folds and cmcl.icm is not None
    learner = cmcl.learner
    every, num_envs = preset("cmcl").maddpg.update_every, preset("cmcl").env.num_envs  # world steps per update
    assert learner.ratio == 1.0 / every and learner.warmup == 3840
    assert learner.start == every * ((3840 - num_envs) // every)  # from the batched step that completes the warm-up
    assert learner.slack == max((1 + 1 / every) / 2, num_envs / every, 1.0)  # a batched env step always fits
    learner.record_insert(3840)
    assert learner.due() == 1  # step 3840 is a multiple of update_every: the first update is due at once
    learner.record_sample(1)
    assert learner.can_insert(num_envs)  # then a whole batched env step fits
    maddpg, acl = pacing_from_config(preset("maddpg")), pacing_from_config(preset("acl"))
    assert (maddpg.teachers, maddpg.icm) == ([], None) and acl.teachers and acl.icm is None


def test_the_service_slack_widens_every_limiter_as_the_replay_server_needs():
    config = preset("cmcl")
    inline, service = pacing_from_config(config), pacing_from_config(config, asynchronous=True)
    chunk, fit = config.env.num_envs * config.env.episode_length, config.service.fit_steps_per_call
    extra = config.service.slack_updates
    assert service.learner.slack == max(chunk / config.maddpg.update_every, 1.0, float(extra))
    assert [t.slack for t in service.teachers] == [max(t.slack, fit) + extra for t in inline.teachers]
    assert service.icm.slack == max(inline.icm.slack, fit) + extra
    assert (service.learner.warmup, service.learner.start) == (inline.learner.warmup, inline.learner.start)


@pytest.mark.parametrize("seed", range(8))
def test_updates_fall_on_algorithm_1s_steps_in_both_forms(seed):
    """Algorithm 1 (§3.8) over B lock-stepped worlds: after each batched env step (B transitions stored), one update
    per env step t of it with t mod update_every == 0 if |D| >= max(1, warmup)."""
    rng = np.random.default_rng(seed)
    every, warmup, b = int(rng.integers(1, 20)), int(rng.integers(0, 200)), int(rng.integers(1, 9))
    config = _with(preset("maddpg"), num_envs=b, update_every=every, warmup=warmup, batch_size=1)
    inline, service = pacing_from_config(config), pacing_from_config(config, asynchronous=True)
    steps, owed = 0, 0
    for _ in range(60):
        inline.record_insert(b)
        service.record_insert(b)
        steps += b
        inline.record_updates(inline.due_updates())
        if steps >= max(1, warmup):  # |D| after this batched step: its B env steps count
            owed += sum(1 for t in range(steps - b + 1, steps + 1) if t % every == 0)
        assert inline.learner.samples == owed, (every, warmup, b, steps)
        status = service.status(np.zeros(0, np.int64))
        assert inline.warm == service.warm == (steps >= max(1, warmup))
        if service.warm:  # the service owes the same updates, within its slack
            assert math.floor(status.update_deficit + 1e-9) == owed
            assert status.allowed_updates == owed + math.floor(service.learner.slack)
        else:
            assert (status.allowed_updates, status.update_deficit) == (0, 0.0)


def test_fit_steps_due_per_update_follow_their_ratio():
    pacing = pacing_from_config(preset("cmcl"))  # steps_per_update 0.5 for the teachers and the ICM
    ratio, folds = preset("cmcl").teachers.steps_per_update, range(len(pacing.teachers))
    for update in range(1, 12):
        pacing.record_updates(1)
        teacher, icm = pacing.due_teacher_steps(), pacing.due_icm_steps()
        pacing.record_teacher_steps(folds, teacher)
        pacing.record_icm_steps(icm)
        assert pacing.teachers[0].samples == pacing.icm.samples == math.floor(update * ratio)
    with pytest.raises(ValueError, match="steps must be 0 without an ICM, got steps=2"):
        pacing_from_config(preset("acl")).record_icm_steps(2)


def test_no_scoring_work_before_the_warm_up_ends():
    config = _with(preset("cmcl"), warmup=100, batch_size=64)
    pacing = pacing_from_config(config, asynchronous=True)
    folds = np.ones(config.teachers.num_folds, np.int64)
    pacing.record_insert(99)
    status = pacing.status(folds)
    assert status.teacher_allowed == (0,) * config.teachers.num_folds and status.icm_allowed == 0
    assert status.scoring_deficit == 0.0 and pacing.teacher_steps_allowed([0, 1]) == 0
    pacing.record_insert(1)
    status = pacing.status(folds)
    assert min(status.teacher_allowed) > 0 and status.icm_allowed > 0 and status.allowed_updates > 0


def test_state_round_trip_and_snapshots_from_before_the_one_warm_up_rule():
    config = preset("cmcl")
    pacing = pacing_from_config(config, asynchronous=True)
    pacing.record_insert(4000)
    pacing.record_updates(7)
    pacing.record_teacher_steps([0, 2], 3)
    pacing.record_icm_steps(2)
    state = pacing.state_dict()
    assert set(state) == {"learner_limit", "teacher_limits", "icm_limit"}  # the replay server's snapshot keys
    fresh = pacing_from_config(config, asynchronous=True)
    fresh.load_state_dict(state)
    assert fresh.state_dict() == state
    # a replay server snapshot written before the rule: no "start", warm-up = maddpg.warmup; counters carry over
    older = {**state, "learner_limit": {k: v for k, v in state["learner_limit"].items() if k != "start"}}
    older["teacher_limits"] = [{k: v for k, v in t.items() if k != "start"} for t in state["teacher_limits"]]
    older["icm_limit"] = {k: v for k, v in state["icm_limit"].items() if k != "start"}
    fresh = pacing_from_config(config, asynchronous=True)
    fresh.load_state_dict(older)
    assert fresh.state_dict() == state
    other = pacing_from_config(_with(config, warmup=1000, batch_size=64), asynchronous=True)
    with pytest.raises(ValueError, match="learner_limit: rate limiter state has warmup=3840, this limiter has "
                                         "warmup=1000"):
        other.load_state_dict(older)
    with pytest.raises(ValueError, match="teacher_limits: the state has 6 folds' limiters, this config 5"):
        fresh.load_state_dict({**state, "teacher_limits": [*state["teacher_limits"], state["teacher_limits"][0]]})


def test_restore_counts_equals_recording_them():
    config = preset("cmcl")
    recorded, restored = pacing_from_config(config), pacing_from_config(config)
    recorded.record_insert(5000)
    recorded.record_updates(70)
    recorded.record_teacher_steps(range(len(recorded.teachers)), 35)
    recorded.record_icm_steps(35)
    restored.restore_counts(env_steps=5000, updates=70, teacher_steps=35, icm_steps=35)
    assert restored.state_dict() == recorded.state_dict()

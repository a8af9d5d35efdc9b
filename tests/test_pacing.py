"""cmcl/replay/pacing.py: the replay server's pacing (both runners schedule the same roles), Algorithm 1's warm-up
rule, and its state across versions."""

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
    config = preset("cmcl")
    cmcl = pacing_from_config(config, asynchronous=True)
    assert len(cmcl.teachers) == config.teachers.num_folds and cmcl.icm is not None
    learner = cmcl.learner
    every, num_envs = config.maddpg.update_every, config.env.num_envs  # world steps per update
    assert learner.ratio == 1.0 / every and learner.warmup == 3840
    assert learner.start == every * ((3840 - num_envs) // every)  # from the batched step that completes the warm-up
    assert [t.ratio for t in cmcl.teachers] == [config.teachers.steps_per_update] * config.teachers.num_folds
    assert cmcl.icm.ratio == config.icm.steps_per_update
    cmcl.record_insert(3840)
    assert cmcl.warm and cmcl.status(np.ones(config.teachers.num_folds, np.int64)).allowed_updates >= 1
    maddpg, acl = (pacing_from_config(preset(a), asynchronous=True) for a in ("maddpg", "acl"))
    assert (maddpg.teachers, maddpg.icm) == ([], None) and acl.teachers and acl.icm is None


def test_the_service_slack_fits_a_chunk_a_call_and_the_drift_between_the_roles():
    """Each limiter's slack: the learner's a rollout chunk's updates (or service.slack_updates, at least one); each
    scorer's one call's fit steps plus service.slack_updates."""
    config = preset("cmcl")
    service = pacing_from_config(config, asynchronous=True)
    chunk, fit = config.env.num_envs * config.env.episode_length, config.service.fit_steps_per_call
    extra = config.service.slack_updates
    assert service.learner.slack == max(chunk / config.maddpg.update_every, 1.0, float(extra))
    assert [t.slack for t in service.teachers] == [fit + extra] * config.teachers.num_folds
    assert service.icm.slack == fit + extra


@pytest.mark.parametrize("seed", range(8))
def test_updates_fall_on_algorithm_1s_steps(seed):
    """Algorithm 1 (§3.8) over B lock-stepped worlds: after each batched env step (B transitions stored), one update
    per env step t of it with t mod update_every == 0 if |D| >= max(1, warmup): the replay server owes those
    updates, within its slack."""
    rng = np.random.default_rng(seed)
    every, warmup, b = int(rng.integers(1, 20)), int(rng.integers(0, 200)), int(rng.integers(1, 9))
    config = _with(preset("maddpg"), num_envs=b, update_every=every, warmup=warmup, batch_size=1)
    service = pacing_from_config(config, asynchronous=True)
    steps, owed = 0, 0
    for _ in range(60):
        service.record_insert(b)
        steps += b
        if steps >= max(1, warmup):  # |D| after this batched step: its B env steps count
            owed += sum(1 for t in range(steps - b + 1, steps + 1) if t % every == 0)
        status = service.status(np.zeros(0, np.int64))
        assert service.warm == (steps >= max(1, warmup))
        if service.warm:  # the service owes the same updates, within its slack
            assert math.floor(status.update_deficit + 1e-9) == owed, (every, warmup, b, steps)
            assert status.allowed_updates == owed + math.floor(service.learner.slack)
        else:
            assert (status.allowed_updates, status.update_deficit) == (0, 0.0)


def test_fit_steps_handed_out_per_update_follow_their_ratio():
    config = preset("cmcl")  # steps_per_update 0.5 for the teachers and the ICM
    pacing = pacing_from_config(config, asynchronous=True)
    pacing.record_insert(config.maddpg.warmup)
    ratio, folds = config.teachers.steps_per_update, range(len(pacing.teachers))
    for update in range(1, 12):
        pacing.record_updates(1)
        teacher, icm = pacing.teacher_steps_allowed(folds), pacing.icm_steps_allowed()
        pacing.record_teacher_steps(folds, teacher)
        pacing.record_icm_steps(icm)
        # everything allowed handed out: the ratio's steps, and the slack's ahead of it, never more
        ahead = math.floor(update * ratio + pacing.teachers[0].slack)
        assert pacing.teachers[0].samples == pacing.icm.samples == ahead
        assert pacing.teacher_steps_allowed(folds) == pacing.icm_steps_allowed() == 0
    with pytest.raises(ValueError, match="steps must be 0 without an ICM, got steps=2"):
        pacing_from_config(preset("acl"), asynchronous=True).record_icm_steps(2)


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


def test_state_round_trip_and_a_state_of_another_setting_is_refused():
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
    other = pacing_from_config(_with(config, warmup=1000, batch_size=64), asynchronous=True)
    with pytest.raises(ValueError, match="learner_limit: rate limiter state has warmup=3840, this limiter has "
                                         "warmup=1000"):
        other.load_state_dict(state)
    with pytest.raises(ValueError, match="teacher_limits: the state has 6 folds' limiters, this config 5"):
        fresh.load_state_dict({**state, "teacher_limits": [*state["teacher_limits"], state["teacher_limits"][0]]})

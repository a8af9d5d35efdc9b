"""The service classes run in-process without Ray, in the order the supervisor chains them: one round of the data
flow through every role, which rows each teacher fits and scores, what the replay server refuses and counts, the
incarnation on every reply, the calls the supervisor issues, and entity networks in every role. What survives a
restart is tests/test_service_inprocess_restart.py."""

import dataclasses
from collections import Counter

import numpy as np
import pytest

from cmcl.config import config_from_dict
from cmcl.replay.messages import CURIOSITY, DIFFICULTY, LearnerFeedback, ReplayStatus, Scorer
from services.roles.icm import ICMWorker
from services.roles.learner import Learner
from services.roles.replay_server import ReplayServer
from services.roles.rollout import RolloutWorker
from services.roles.teachers import TeacherWorker
from services.runtime.call_budget import calls_to_issue
from services.runtime.placement import teacher_groups
from tests.in_process import in_process_config, roles


def test_one_round_of_the_data_flow_reaches_every_role():
    cfg = in_process_config("cmcl", service={"score_rows_per_call": 360})  # every row scored in one call
    replay, learner, worker, teachers, icm = roles(cfg)
    published = learner.publish()
    for _ in range(3):
        chunk, report = worker.rollout(published)
        status = replay.insert(chunk)
    assert status.size == 360 and status.episodes == 12 and report.rollout.episodes == 12
    lam0 = status.lam
    for k, teacher in enumerate(teachers):
        work, _ = replay.work(Scorer(DIFFICULTY, (k,)), 2)
        assert (replay.replay.storage.fold[work.score.slots] != k).all(), "teacher k scores other folds only"
        scores, _ = teacher.score(work, published)
        replay.write(scores)
    scored = replay.replay.storage.scored["difficulty"][:360]
    assert scored.all(), "after all K teachers scored, every row has a difficulty"
    work, _ = replay.work(Scorer(CURIOSITY), 2)
    replay.write(icm.score(work)[0])
    assert replay.replay.storage.scored["curiosity"][:200].any()
    batch, status = replay.sample(4)
    assert batch.rows["obs"].shape == (4, 4, 16, 4, 18)
    feedback, report = learner.update(batch)
    replay.learner_result(feedback)
    assert report.learner.updates == 4 and status.updates == 4
    for kinds in report.learner.losses.values():  # run.progress_signal = "normalised_td" reads critic_normalised
        assert set(kinds) == {"critic", "actor", "critic_normalised"} and kinds["critic_normalised"] >= 0
    assert lam0 == pytest.approx(0.1 + (360 - 96) * replay.schedule.stride), "λ moves with env steps after warm-up"
    assert learner.publish()["version"] == 1
    sampling = replay.report().replay  # the sampling diagnostics of every agent reach the metrics report
    assert set(sampling.agent_sampling_ess) == {"0", "1", "2", "3"} and 0 < sampling.agent_sampling_ess["0"] <= 1
    assert set(sampling.reward_rows_sampled) == set(sampling.reward_rows_buffer) == {"0", "1", "2", "3"}


def test_teacher_fit_batches_come_only_from_its_own_fold():
    cfg = in_process_config("acl")
    replay, worker = ReplayServer(cfg), RolloutWorker(cfg, 0, 0)
    for _ in range(3):
        replay.insert(worker.rollout(None)[0])
    folds = replay.replay.storage.fold
    for k in range(3):
        work, _ = replay.work(Scorer(DIFFICULTY, (k,)), 2)
        assert work.fit["obs"].shape[:4] == (2, 1, 1, 16) and work.fit_slots.shape == (2, 1, 1, 16)
        assert (folds[work.fit_slots] == k).all()
        assert (folds[work.score.slots] != k).all()


def test_duplicate_bad_and_stale_inputs_are_refused_and_counted():
    cfg = in_process_config("per")
    replay, worker = ReplayServer(cfg), RolloutWorker(cfg, 0, 0)
    chunk, _ = worker.rollout(None)
    assert replay.insert(chunk).accepted == 120
    again = replay.insert(chunk)
    assert again.accepted == 0 and "duplicate" in again.error
    good = worker.rollout(None)[0]
    refused = replay.insert(dataclasses.replace(good, obs=np.full_like(good.obs, np.nan)))
    assert refused.accepted == 0 and "chunk.obs: must be finite" in refused.error and refused.size == 120
    assert replay.insert({"obs": 1}).error.startswith("bad_chunk")
    for _ in range(3):  # wrap the 360-slot buffer: the first chunk's slots get new generations
        replay.insert(worker.rollout(None)[0])
    slots = np.arange(10).reshape(1, 1, -1).repeat(4, 1)  # [n=1, N=4, S=10]
    replay.learner_result(LearnerFeedback(slots, np.zeros_like(slots), np.ones((1, 4, 10), np.float32)))
    assert replay.rejected == {"duplicate": 1, "bad_chunk": 2}  # refused input, each reason counted
    assert replay.stale_scores == 40  # stale score updates: dropped by design, counted apart


def test_icm_actor_refuses_a_config_without_curiosity():
    with pytest.raises(ValueError, match="curiosity"):
        ICMWorker(in_process_config("acl"), 0)


@pytest.mark.parametrize("shared", [False, True], ids=["own_teachers", "shared_teachers"])
def test_one_actor_can_host_every_fold_without_leaking_a_rows_own_fold(shared):
    cfg = in_process_config("acl", service={"teacher_actors": 1, "score_rows_per_call": 360},
                            teachers={"networks": "shared" if shared else "per_agent"})
    assert teacher_groups(config_from_dict(cfg)) == [[0, 1, 2]]
    replay, worker, learner = ReplayServer(cfg), RolloutWorker(cfg, 0, 0), Learner(cfg, 0)
    teacher = TeacherWorker(cfg, [0, 1, 2], 0)
    assert teacher.teachers.net.layers[1].weight.shape[0] == (3 if shared else 12)  # per fold, or per (agent, fold)
    for _ in range(3):
        replay.insert(worker.rollout(None)[0])
    work, _ = replay.work(Scorer(DIFFICULTY, (0, 1, 2)), 2)
    folds = replay.replay.storage.fold
    assert work.fit["obs"].shape[:4] == (2, 1, 3, 16)
    assert (folds[work.fit_slots] == np.arange(3)[None, None, :, None]).all(), "fit batch i comes from fold i"
    scores, _ = teacher.score(work, learner.publish())
    assert scores.values.shape == (360, 4, 3)  # [M, A_t, F]
    replay.write(scores)
    rows = np.arange(360)
    stamps = replay.scoring.difficulty.stamps(rows, replay.replay.generations(rows))
    assert (stamps[rows, folds[rows]] == -1).all(), "no row is scored by its own fold's teacher"
    assert (stamps >= 0).sum(1).min() == 2, "every row scored by the K-1 blind teachers"
    assert replay.replay.storage.scored["difficulty"][:360].all()


def test_chunks_are_stored_exactly_once_in_any_order():
    cfg = in_process_config("maddpg")
    replay, worker = ReplayServer(cfg), RolloutWorker(cfg, 0, 0)
    chunks = [worker.rollout(None)[0] for _ in range(3)]
    for chunk in (chunks[2], chunks[0], chunks[1]):  # the later chunk arrives first: none is lost
        assert replay.insert(chunk).accepted == 120
    for chunk in chunks:
        assert "duplicate" in replay.insert(chunk).error, "none is stored twice"
    assert replay.replay.size == 360 and replay.counters["episodes"] == 12
    assert replay.ledger.watermark[chunks[0].writer_key] == 2 and not replay.ledger.pending[chunks[0].writer_key]


@pytest.mark.parametrize("field, value, message", [
    ("env_index", lambda c: c.env_index + 10**9, "chunk.env_index: must be < 4"),
    ("act", lambda c: np.full_like(c.act, 5.0), "actions must lie in"),
    ("done", lambda c: np.full_like(c.done, 0.5), "chunk.done: must be 0 or 1"),
])
def test_a_chunk_that_would_corrupt_the_accounting_is_refused(field, value, message):
    cfg = in_process_config("maddpg")
    replay, worker = ReplayServer(cfg), RolloutWorker(cfg, 0, 0)
    chunk = worker.rollout(None)[0]
    refused = replay.insert(dataclasses.replace(chunk, **{field: value(chunk)}))
    assert message in refused.error and refused.episodes == 0 and replay.replay.size == 0
    assert replay.insert(chunk).accepted == 120, "the good chunk with the same seq is still accepted"


def test_every_reply_carries_its_actors_incarnation_and_a_bad_one_is_refused():
    cfg = in_process_config("cmcl")
    replay, learner, worker, teachers, icm = roles(cfg)
    for _ in range(3):
        chunk, report = worker.rollout(None)
        assert chunk.incarnation == report.incarnation == worker.incarnation
        replay.insert(chunk)
    feedback, report = learner.update(replay.sample(2)[0])
    assert feedback.incarnation == report.incarnation == learner.incarnation
    scores, report = teachers[0].score(replay.work(Scorer(DIFFICULTY, (0,)), 2)[0], learner.publish())
    assert scores.incarnation == report.incarnation == teachers[0].incarnation
    curiosity, report = icm.score(replay.work(Scorer(CURIOSITY), 2)[0])
    assert curiosity.incarnation == report.incarnation == icm.incarnation
    assert replay.status().incarnation == replay.incarnation
    assert len({worker.incarnation, learner.incarnation, teachers[0].incarnation, icm.incarnation}) == 4
    refused = replay.write(dataclasses.replace(scores, incarnation=["not", "a", "string"]))
    assert refused.error.startswith("bad_scores: Scores.incarnation must be a string")
    refused = replay.learner_result(dataclasses.replace(feedback, incarnation="x" * 65))
    assert refused.error.startswith("bad_feedback: LearnerFeedback.incarnation")
    assert replay.rejected["bad_scores"] == 1 and replay.rejected["bad_feedback"] == 1


def test_the_supervisor_issues_the_calls_the_allowances_leave_room_for():
    cfg = config_from_dict(in_process_config("cmcl"))  # 4 worlds × 30 steps per chunk, 4 updates / 2 fit steps per call
    chunk = 4 * 30
    status = ReplayStatus(allowed_updates=0, allowed_inserts=3 * chunk, update_deficit=0.0, scoring_deficit=0.0,
                          teacher_allowed=(0, 0, 0), icm_allowed=0, updates_held_by="warmup", size=0, env_steps=0,
                          episodes=0, updates=0, lam=0.1, incarnation="i")
    groups = [[0], [1, 2]]
    calls = calls_to_issue(status, Counter(), cfg, 2, groups, icm=True)
    assert (calls[("rollout", 0)], calls[("rollout", 1)]) == (2, 1), "3 chunks' worth of inserts, 2 per worker"
    assert sum(calls[k] for k in calls if k[0] != "rollout") == 0, "no learner / scoring work before warm-up"
    assert not sum(calls_to_issue(status, Counter(), cfg, 2, groups, icm=True, rollouts=False).values())
    near_end = dataclasses.replace(status, episodes=cfg.run.episodes - 4)  # one chunk of 4 episodes left
    assert calls_to_issue(near_end, Counter(), cfg, 2, groups, icm=True)[("rollout", 0)] == 1
    warm = dataclasses.replace(status, allowed_updates=5, teacher_allowed=(4, 2, 1), icm_allowed=3)
    busy = Counter({("learner", 0): 1, ("teacher", 0): 1, ("icm", 0): 1, ("rollout", 0): 2})
    calls = calls_to_issue(warm, busy, cfg, 2, groups, icm=True)
    assert calls[("learner", 0)] == 1  # 5 allowed, 4 held by the call in flight: 1 more call for the last one
    assert calls[("teacher", 0)] == 1 and calls[("teacher", 1)] == 1  # room 4 - 2 = 2; min(2, 1) = 1
    assert calls[("icm", 0)] == 1 and (calls[("rollout", 0)], calls[("rollout", 1)]) == (0, 1)
    assert calls_to_issue(warm, busy, cfg, 2, groups, icm=False)[("icm", 0)] == 0


@pytest.mark.parametrize("nearest", [0, 2])
def test_entity_networks_run_through_every_role(nearest):
    """maddpg.networks = "entity": the rollout worker acts with the numpy entity actor, the learner and the
    teachers' target networks load what the learner publishes; icm.networks = "entity" scores curiosity. With
    maddpg.entity_nearest = k every role's actor and critic read the k nearest entities of each kind."""
    from cmcl.rollout.policy import NumpyEntityPolicy

    cfg = in_process_config("cmcl", maddpg={"networks": "entity", "entity_nearest": nearest},
                            service={"score_rows_per_call": 360}, icm={"networks": "entity"})
    replay, learner, worker, teachers, icm = roles(cfg)
    for _ in range(3):
        replay.insert(worker.rollout(None)[0])
    assert isinstance(worker.policy, NumpyEntityPolicy) and worker.policy.nearest == nearest
    assert learner.maddpg.actor.nearest == teachers[0].targets.target_critic.nearest == nearest
    learner.update(replay.sample(4)[0])
    published = learner.publish()
    assert "encoder.entity.weight" in published["weights"]["target_critic"]
    chunk, _ = worker.rollout(published)
    assert worker.version == published["version"] and np.isfinite(chunk.act).all()
    work, _ = replay.work(Scorer(DIFFICULTY, (0,)), 2)
    scores, _ = teachers[0].score(work, published)
    assert np.isfinite(scores.values).all()
    work, _ = replay.work(Scorer(CURIOSITY), 2)
    assert np.isfinite(icm.score(work)[0].values).all()


def test_a_teacher_actor_hosts_entity_teachers():
    cfg = in_process_config("acl", service={"teacher_actors": 1, "score_rows_per_call": 360},
                            teachers={"networks": "entity"})
    replay, worker, learner = ReplayServer(cfg), RolloutWorker(cfg, 0, 0), Learner(cfg, 0)
    teacher = TeacherWorker(cfg, [0, 1, 2], 0)
    assert teacher.teachers.networks == "entity" and teacher.teachers.num_folds == 3
    for _ in range(3):
        replay.insert(worker.rollout(None)[0])
    work, _ = replay.work(Scorer(DIFFICULTY, (0, 1, 2)), 2)
    scores, _ = teacher.score(work, learner.publish())
    assert scores.values.shape == (360, 4, 3) and np.isfinite(scores.values).all()

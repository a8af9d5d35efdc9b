"""The inline loop and the service shells give the same numbers on the same inputs (issue 8).

Both runners call the same step functions; these tests check that the shells feed them the same things: one
buffer's contents, teachers with the same weights, the same sampler states. Inline: `cmcl.loop.InlineLoop`.
Service: `services.replay_server.ReplayServer` with `TeacherWorker`s (one fold each), the `ICMWorker` and the
`Learner`, run in-process (no Ray needed for the arithmetic).
"""

import copy
import dataclasses

import numpy as np
import pytest
import torch

from cmcl.config import TeamConfig, config_from_dict
from cmcl.learners.network_steps import choose_minibatch, learner_update
from cmcl.loop import InlineLoop
from cmcl.messages import LearnerFeedback
from cmcl.replay import buffer_steps
from cmcl.replay.registry import ALGORITHMS, REGISTRY
from cmcl.system import beta_is
from services.icm import ICMWorker
from services.learner import Learner
from services.replay_server import ReplayServer
from services.rollout import RolloutWorker
from services.teachers import TeacherWorker
from tests.in_process import in_process_config

# every registered rule and its controls: the agreement holds for each (issue 36)
TEACHER_RULES = [a for a in ALGORITHMS if REGISTRY[a].needs(TeamConfig(algorithm=a)).teachers]
CONTROLS = ("none", "permuted", "reversed")


def twins(algorithm, transform="none", actor_batch="rule"):
    """A replay server and an inline loop whose buffers hold the same three rollout chunks."""
    cfg = in_process_config(algorithm, service={"score_rows_per_call": 360})  # every row scored in one call
    cfg["teams"]["agent"]["priority"]["difficulty_transform"] = transform
    for team in cfg["teams"].values():
        team["actor_batch"] = actor_batch
    server, worker = ReplayServer(cfg), RolloutWorker(cfg, 0, 0)
    loop = InlineLoop(config_from_dict(cfg), progress=None)
    for _ in range(3):
        chunk, _ = worker.rollout(None)
        episodes = server.counters["episodes"]
        server.insert(chunk)
        loop.replay.add(chunk.obs, chunk.act, chunk.rew, chunk.next_obs, chunk.done, episodes + chunk.env_index,
                        chunk.policy_version)
    assert server.replay.size == loop.replay.size == 360
    np.testing.assert_array_equal(server.replay.storage.fold, loop.replay.storage.fold)
    return cfg, server, loop


def teacher_worker_like(cfg, loop, fold):
    """The service's teacher of `fold`, holding the inline ensemble's weights of that fold and its target nets."""
    worker = TeacherWorker(cfg, [fold], 0)
    k = loop.teachers.num_folds
    members = [a * k + fold for a in range(loop.teachers.num_agents)]  # inline member a·K + i -> worker member a
    with torch.no_grad():
        for ours, theirs in zip(worker.teachers.net.layers, loop.teachers.net.layers, strict=True):
            ours.weight.copy_(theirs.weight[members])
            ours.bias.copy_(theirs.bias[members])
    worker.targets, worker.version = loop.maddpg, 0  # the learner's target nets, as published at version 0
    return worker


def without_fit(work):
    """The same work with zero fit steps, so that scoring happens with the weights as they are."""
    return dataclasses.replace(work, fit={k: v[:0] for k, v in work.fit.items()})


@pytest.mark.parametrize("transform", CONTROLS)
@pytest.mark.parametrize("algorithm", TEACHER_RULES)
def test_difficulty_and_priorities_agree(algorithm, transform):
    cfg, server, loop = twins(algorithm, transform)
    for fold in range(loop.teachers.num_folds):  # service: every teacher scores the rows of the other folds
        teacher = teacher_worker_like(cfg, loop, fold)
        work, _ = server.teacher_work([fold], 1)
        assert work.score.slots.size == (server.replay.storage.fold[:360] != fold).sum()
        scores, _ = teacher.step(without_fit(work), {"version": 0, "weights": {}})
        server.write_teacher_scores(scores)
    if algorithm == "cmcl":
        icm = ICMWorker(cfg, 0)
        icm.icm.load_state_dict(copy.deepcopy(loop.icm.state_dict()))
        work, _ = server.icm_work(1)
        server.write_curiosity(icm.step(without_fit(work))[0])
    everything = np.arange(360)
    loop._score(buffer_steps.score_rows(loop.replay, everything))  # inline: all K teachers (and the ICM) at once
    for column in ("difficulty", "curiosity"):
        ours, theirs = loop.replay.storage, server.replay.storage
        np.testing.assert_array_equal(ours.scored[column], theirs.scored[column])
        np.testing.assert_allclose(ours.scores[column], theirs.scores[column], rtol=1e-5, atol=1e-7)
    lam = 0.4
    inline = loop.replay.recompute_priorities(lam, details=True)
    service = server.replay.recompute_priorities(lam, details=True)
    for key in ("c_hat", "kp", "cp", "priority"):
        np.testing.assert_allclose(inline[key], service[key], rtol=1e-5, atol=1e-7, err_msg=key)
    np.testing.assert_allclose(loop.replay.sampling_distribution(), server.replay.sampling_distribution(),
                               rtol=1e-5, atol=1e-9)


@pytest.mark.parametrize(("transform", "actor_batch"), [("none", "rule"), ("permuted", "rule"), ("none", "uniform")])
@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_learner_batch_feedback_and_update_agree(algorithm, transform, actor_batch):
    cfg, server, loop = twins(algorithm, transform, actor_batch)
    rngs = [copy.deepcopy(g) for g in server.sampler_rngs]
    batch, _ = server.sample(1)
    beta = beta_is(loop.config, server.counters["inserts"])
    betas = [beta if w else 0.0 for w in loop.layout.importance_weights]
    inline = buffer_steps.sample_owner_batches(loop.replay, 1, loop.config.maddpg.batch_size, rngs, betas,
                                               loop.layout.candidates, loop.layout.uniform_actor,
                                               loop.layout.permuted_select)
    np.testing.assert_array_equal(batch.slots, inline.slots)
    assert (batch.select_u is None) == (inline.select_u is None) == (loop.layout.candidates == 1)
    if batch.select_u is not None:  # LaBER: m·B candidates, and the same numbers to pick with
        assert batch.slots.shape[-1] == loop.layout.candidates * loop.config.maddpg.batch_size
        np.testing.assert_array_equal(batch.select_u, inline.select_u)
    shuffled = loop.layout.candidates > 1 and transform == "permuted"  # LaBER's candidates under the control
    assert any(loop.layout.permuted_select) == shuffled
    assert (batch.select_order is None) == (inline.select_order is None) == (not shuffled)
    if shuffled:  # the same orders to read the candidates' |δ| in, from the same control generator's state
        np.testing.assert_array_equal(batch.select_order, inline.select_order)
    uniform_actor = actor_batch == "uniform" and REGISTRY[algorithm].prioritised  # maddpg's batch is uniform already
    assert (batch.actor is None) == (inline.actor is None) == (not uniform_actor)
    if uniform_actor:  # the actors' own uniform rows, drawn alike
        np.testing.assert_array_equal(batch.actor.slots, inline.actor.slots)
        for key in ("obs", "act"):
            np.testing.assert_array_equal(batch.actor.rows[key], inline.actor.rows[key])
    np.testing.assert_array_equal(batch.is_weights, inline.is_weights)
    for key in ("obs", "act", "rew", "next_obs", "done"):
        np.testing.assert_array_equal(batch.rows[key], inline.rows[key])
    learner = Learner(cfg, 0)
    learner.maddpg.load_state_dict(copy.deepcopy(loop.maddpg.state_dict()))
    feedback, _ = learner.update(batch)
    minibatch, slots, generations = choose_minibatch(loop.maddpg, inline, 0, any(loop.layout.importance_weights),
                                                     loop.layout.select)
    np.testing.assert_array_equal(feedback.slots[0], slots)  # the rows trained on, picked alike
    if batch.select_u is None:  # the feedback is about the critic's rows, never the actors' own
        np.testing.assert_array_equal(feedback.slots, batch.slots)
    inline_stats = learner_update(loop.maddpg, minibatch)
    np.testing.assert_allclose(feedback.td_abs[0], inline_stats["td_abs"], rtol=1e-6)
    target = inline_stats.get("target_td_abs")
    assert (feedback.target_td_abs is None) == (target is None) == ("target_td_abs" not in loop.layout.learner_scores)
    if target is not None:
        np.testing.assert_allclose(feedback.target_td_abs[0], target, rtol=1e-6)
    for part in ("critic", "actor"):
        for name, value in loop.maddpg.state_dict()[part].items():
            torch.testing.assert_close(learner.maddpg.state_dict()[part][name], value)
    server.learner_result(feedback)
    buffer_steps.apply_learner_feedback(loop.replay, loop.layout, LearnerFeedback(
        slots[None], generations[None], inline_stats["td_abs"][None],
        target_td_abs=None if target is None else target[None]))
    if loop.replay.recomputes:  # both sides rebuild at the same λ, the permuted control from the same state (the
        # server recomputed once more, before it sampled)
        loop.replay.control_rng = copy.deepcopy(server.replay.control_rng)
        loop.replay.recompute_priorities(0.4)
        server.replay.recompute_priorities(0.4)
    for agent in range(loop.layout.num_agents):
        slots = np.unique(feedback.slots[0, agent])
        np.testing.assert_allclose(server.replay.probabilities(agent, slots), loop.replay.probabilities(agent, slots),
                                   rtol=1e-6)


def test_per_agent_teacher_fit_batches_are_drawn_on_the_service_as_inline():
    """teachers.fit_batch = "per_agent" is honoured by both runners: one fit batch per teacher agent per fold."""
    cfg = in_process_config("cmcl", teachers={"fit_batch": "per_agent"})
    server, worker = ReplayServer(cfg), RolloutWorker(cfg, 0, 0)
    for _ in range(3):
        server.insert(worker.rollout(None)[0])
    work, _ = server.teacher_work([0], 1)
    a_t = len(server.layout.teacher_agents)
    assert a_t > 1 and work.fit_slots.shape[:3] == (1, a_t, 1)
    teacher = TeacherWorker(cfg, [0], 0)
    scores, _ = teacher.step(work, Learner(cfg, 0).publish())
    assert scores is not None and np.isfinite(scores.errors).all()

"""The roles compute what the step functions they call compute, and the service's two teacher layouts
agree.

There is one implementation of each step (cmcl.replay.buffer_steps, cmcl.learners.network_steps); these tests check
that the roles (services/: the `ReplayServer`, `TeacherWorker`s, the `ICMWorker` and the `Learner`, built in-process,
no Ray needed for the arithmetic) feed them the right things: the replay server's batches, the learner's feedback
and the priorities it leads to against the step functions called directly on copies of the same state; and one
stacked teacher holding every fold (the inline runner's, and a service with one teacher CPU) against one teacher
per fold (a service with a CPU per fold) on the same buffer.
"""

import copy
import dataclasses

import numpy as np
import pytest
import torch

from cmcl.config import TeamConfig
from cmcl.learners.network_steps import choose_minibatch, learner_update, rule_scores
from cmcl.replay import buffer_steps
from cmcl.replay.messages import CURIOSITY, DIFFICULTY, LearnerFeedback, RuleScore, Scorer
from cmcl.replay.registry import ALGORITHMS, REGISTRY
from cmcl.system import beta_is
from services.roles.icm import ICMWorker
from services.roles.learner import Learner
from services.roles.replay_server import ReplayServer
from services.roles.rollout import RolloutWorker
from services.roles.teachers import TeacherWorker
from services.runtime.common import actor_setup
from tests.in_process import in_process_config

# every registered rule and its controls: the agreement holds for each
TEACHER_RULES = [a for a in ALGORITHMS if REGISTRY[a].needs(TeamConfig(algorithm=a)).teachers]
CONTROLS = ("none", "permuted", "reversed")


def filled(algorithm, transform="none", actor_batch="rule", servers=1):
    """(config dict, `servers` replay servers whose buffers hold the same three rollout chunks)."""
    cfg = in_process_config(algorithm, service={"score_rows_per_call": 360})  # every row scored in one call
    cfg["teams"]["agent"]["priority"]["difficulty_transform"] = transform
    for team in cfg["teams"].values():
        team["actor_batch"] = actor_batch
    replicas, worker = [ReplayServer(cfg) for _ in range(servers)], RolloutWorker(cfg, 0, 0)
    for _ in range(3):
        chunk, _ = worker.rollout(None)
        for server in replicas:
            server.insert(chunk)
    for server in replicas:
        assert server.replay.size == 360
        np.testing.assert_array_equal(server.replay.storage.fold, replicas[0].replay.storage.fold)
    return cfg, replicas


def one_fold_of(cfg, stacked, fold):
    """A teacher of `fold` alone, holding the stacked ensemble's weights of that fold."""
    worker = TeacherWorker(cfg, [fold], 0)
    k = len(stacked.folds)
    members = [a * k + fold for a in range(len(stacked.layout.teacher_agents))]  # stacked member a·K + i -> a
    with torch.no_grad():
        for ours, theirs in zip(worker.teachers.net.layers, stacked.teachers.net.layers, strict=True):
            ours.weight.copy_(theirs.weight[members])
            ours.bias.copy_(theirs.bias[members])
    return worker


def without_fit(work):
    """The same work with zero fit steps, so that scoring happens with the weights as they are."""
    return dataclasses.replace(work, fit={k: v[:0] for k, v in work.fit.items()})


@pytest.mark.parametrize("transform", CONTROLS)
@pytest.mark.parametrize("algorithm", TEACHER_RULES)
def test_one_stacked_teacher_scores_and_prioritises_as_one_teacher_per_fold(algorithm, transform):
    cfg, (per_fold, one) = filled(algorithm, transform, servers=2)
    k = cfg["teachers"]["num_folds"]
    published = Learner(cfg, 0).publish()  # the learner's target nets, as published at its version 0
    stacked = TeacherWorker(cfg, list(range(k)), 0)
    work, _ = one.work(Scorer(DIFFICULTY, tuple(range(k))), 1)
    one.write(stacked.score(without_fit(work), published)[0])
    for fold in range(k):  # every teacher scores the rows of the other folds
        work, _ = per_fold.work(Scorer(DIFFICULTY, (fold,)), 1)
        assert work.score.slots.size == (per_fold.replay.storage.fold[:360] != fold).sum()
        scores, _ = one_fold_of(cfg, stacked, fold).score(without_fit(work), published)
        per_fold.write(scores)
    if algorithm == "cmcl":
        icm = ICMWorker(cfg, 0)
        for server in (per_fold, one):
            work, _ = server.work(Scorer(CURIOSITY), 1)
            server.write(icm.score(without_fit(work))[0])
    ours, theirs = one.replay.storage, per_fold.replay.storage
    for column in ("difficulty", "curiosity"):
        np.testing.assert_array_equal(ours.scored[column], theirs.scored[column])
        np.testing.assert_allclose(ours.scores[column], theirs.scores[column], rtol=1e-5, atol=1e-7)
    assert ours.scored["difficulty"][:360].all()
    lam = 0.4
    stacked_terms = one.replay.recompute_priorities(lam, details=True)
    fold_terms = per_fold.replay.recompute_priorities(lam, details=True)
    for key in ("c_hat", "kp", "cp", "priority"):
        np.testing.assert_allclose(stacked_terms[key], fold_terms[key], rtol=1e-5, atol=1e-7, err_msg=key)
    np.testing.assert_allclose(one.replay.sampling_distribution(), per_fold.replay.sampling_distribution(),
                               rtol=1e-5, atol=1e-9)


@pytest.mark.parametrize(("transform", "actor_batch"), [("none", "rule"), ("permuted", "rule"), ("none", "uniform")])
@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_the_roles_batch_feedback_and_priorities_are_the_step_functions(algorithm, transform, actor_batch):
    """The replay server's batch, the learner's update and feedback, and the priorities after it: as
    buffer_steps / network_steps compute them directly, on copies of the same buffer, samplers and networks."""
    cfg, (server,) = filled(algorithm, transform, actor_batch)
    config, layout = actor_setup(cfg), server.layout
    server._maybe_recompute()  # the priorities the batch is drawn from (sample() recomputes when due)
    direct, rngs = copy.deepcopy(server.replay), copy.deepcopy(server.sampler_rngs)
    batch, _ = server.sample(1)
    beta = beta_is(config, server.counters["inserts"])
    betas = [beta if w else 0.0 for w in layout.importance_weights]
    drawn = buffer_steps.sample_owner_batches(direct, 1, config.maddpg.batch_size, rngs, betas, layout.candidates,
                                              layout.uniform_actor, layout.permuted_select)
    np.testing.assert_array_equal(batch.slots, drawn.slots)
    assert (batch.select_u is None) == (drawn.select_u is None) == (layout.candidates == 1)
    if batch.select_u is not None:  # LaBER: m·B candidates, and the same numbers to pick with
        assert batch.slots.shape[-1] == layout.candidates * config.maddpg.batch_size
        np.testing.assert_array_equal(batch.select_u, drawn.select_u)
    shuffled = layout.candidates > 1 and transform == "permuted"  # LaBER's candidates under the control
    assert any(layout.permuted_select) == shuffled
    assert (batch.select_order is None) == (drawn.select_order is None) == (not shuffled)
    if shuffled:  # the same orders to read the candidates' |δ| in, from the same control generator's state
        np.testing.assert_array_equal(batch.select_order, drawn.select_order)
    uniform_actor = actor_batch == "uniform" and REGISTRY[algorithm].prioritised  # maddpg's batch is uniform already
    assert (batch.actor is None) == (drawn.actor is None) == (not uniform_actor)
    if uniform_actor:  # the actors' own uniform rows, drawn alike
        np.testing.assert_array_equal(batch.actor.slots, drawn.actor.slots)
        for key in ("obs", "act"):
            np.testing.assert_array_equal(batch.actor.rows[key], drawn.actor.rows[key])
    np.testing.assert_array_equal(batch.is_weights, drawn.is_weights)
    for key in ("obs", "act", "rew", "next_obs", "done"):
        np.testing.assert_array_equal(batch.rows[key], drawn.rows[key])
    learner = Learner(cfg, 0)
    maddpg = copy.deepcopy(learner.maddpg)
    feedback, _ = learner.update(batch)
    minibatch, slots, generations = choose_minibatch(maddpg, drawn, 0, any(layout.importance_weights),
                                                     layout.select, layout.pick)
    np.testing.assert_array_equal(feedback.slots[0], slots)  # the rows trained on, picked alike
    if batch.select_u is None:  # the feedback is about the critic's rows, never the actors' own
        np.testing.assert_array_equal(feedback.slots, batch.slots)
    stats = learner_update(maddpg, minibatch)
    np.testing.assert_allclose(feedback.td_abs[0], stats["td_abs"], rtol=1e-6)
    own = rule_scores(layout.rule_scores, stats, minibatch)  # the rules' own learner scores (ReLo's target |δ|)
    assert [s.name for s in feedback.rule_scores] == list(own) == [s.name for s in layout.rule_scores]
    for score in feedback.rule_scores:
        np.testing.assert_allclose(score.values[0], own[score.name], rtol=1e-6)
    for part in ("critic", "actor"):
        for name, value in maddpg.state_dict()[part].items():
            torch.testing.assert_close(learner.maddpg.state_dict()[part][name], value)
    server.learner_result(feedback)
    buffer_steps.apply_learner_feedback(direct, layout, LearnerFeedback(
        slots[None], generations[None], stats["td_abs"][None],
        rule_scores=tuple(RuleScore(name, values[None]) for name, values in own.items())))
    if direct.recomputes:  # both rebuild at the same λ, the permuted control from the same state
        direct.control_rng = copy.deepcopy(server.replay.control_rng)
        direct.recompute_priorities(0.4)
        server.replay.recompute_priorities(0.4)
    for agent in range(layout.num_agents):
        rows = np.unique(feedback.slots[0, agent])
        np.testing.assert_allclose(server.replay.probabilities(agent, rows), direct.probabilities(agent, rows),
                                   rtol=1e-6)


def test_per_agent_teacher_fit_batches_are_drawn_one_per_teacher_agent():
    """teachers.fit_batch = "per_agent": one fit batch per teacher agent per fold."""
    cfg = in_process_config("cmcl", teachers={"fit_batch": "per_agent"})
    server, worker = ReplayServer(cfg), RolloutWorker(cfg, 0, 0)
    for _ in range(3):
        server.insert(worker.rollout(None)[0])
    work, _ = server.work(Scorer(DIFFICULTY, (0,)), 1)
    a_t = len(server.layout.teacher_agents)
    assert a_t > 1 and work.fit_slots.shape[:3] == (1, a_t, 1)
    teacher = TeacherWorker(cfg, [0], 0)
    scores, _ = teacher.score(work, Learner(cfg, 0).publish())
    assert scores is not None and np.isfinite(scores.values).all()

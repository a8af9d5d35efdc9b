"""maddpg.holder_rule "seated": an agent seated on a landmark (within the cover radius of its nearest one)
holds only that landmark, so a landmark it covers beside its own reads as held by the nearest agent seated nowhere
else. Its values on hand-built views (torch, the networks' slot path and the numpy twin), the three agreeing on random
views, "nearest" unchanged, and the entity actor and its numpy twin acting alike under it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from cmcl.envs.entities import spread_layout
from cmcl.learners.entity.holder import holder_margin, holder_margin_of_slots, holder_slots
from cmcl.rollout.policy import HOLDER_ALONE
from cmcl.rollout.policy import holder_margin as numpy_margin

TYPES = slice(2, 4)  # navigation's type one-hot (landmark, agent) after the 2 raw features


def view(*rows: tuple[float, float, str]) -> np.ndarray:
    """Entity rows [dx, dy, landmark, agent] float32[E, 4] from (dx, dy, "l" or "a")."""
    return np.array([[x, y, float(kind == "l"), float(kind == "a")] for x, y, kind in rows], np.float32)


def margins(entities: np.ndarray, mask: np.ndarray, rule: str) -> list[np.ndarray]:
    """The margin by the generic torch function and the numpy twin."""
    t = holder_margin(torch.from_numpy(entities), torch.from_numpy(mask), TYPES, rule).numpy()
    return [t, numpy_margin(entities, mask, TYPES, rule)]


def test_an_agent_seated_on_two_landmarks_holds_only_its_nearest():
    # the viewer at the origin; landmarks A (0.5, 0) and B (0.5, 0.15); agent X at (0.5, 0.05) covers both (0.05 and
    # 0.1 away) and sits on A, its nearest; agent Y at (-0.55, 0) sits on C (-0.6, 0); agent Z at (0, 0.5) sits nowhere
    v = view((0.5, 0.0, "l"), (0.5, 0.15, "l"), (-0.6, 0.0, "l"), (0.5, 0.05, "a"), (-0.55, 0.0, "a"), (0.0, 0.5, "a"))
    mask = np.ones((2, 6), bool)
    mask[1, 5] = False  # without Z every other agent is seated elsewhere: B is held by nobody
    b = np.hypot(0.5, 0.15)
    for out in margins(np.stack([v, v]), mask, "seated"):
        np.testing.assert_allclose(out[0, :, 0], [0.05 - 0.5, np.hypot(0.5, 0.35) - b, 0.05 - 0.6, 0, 0, 0],
                                   atol=1e-6)
        np.testing.assert_allclose(out[1, :3, 0], [0.05 - 0.5, HOLDER_ALONE, 0.05 - 0.6], atol=1e-6)
    for out in margins(np.stack([v, v]), mask, "nearest"):  # the old rule: X holds B too
        np.testing.assert_allclose(out[:, 1, 0], [0.1 - b, 0.1 - b], atol=1e-6)


def test_agents_seated_nowhere_count_for_every_landmark_as_under_the_nearest_rule():
    v = view((0.5, 0.0, "l"), (0.9, 0.0, "l"), (0.7, 0.0, "a"), (0.2, 0.3, "a"))  # nobody within 0.1 of a landmark
    mask = np.array([[True, True, True, True], [True, False, True, True]])
    for seated, nearest in zip(margins(np.stack([v, v]), mask, "seated"), margins(np.stack([v, v]), mask, "nearest"),
                               strict=True):
        np.testing.assert_array_equal(seated, nearest)


@pytest.mark.parametrize("rule", ["nearest", "seated"])
def test_the_slot_path_the_generic_path_and_the_numpy_twin_agree_on_random_views(rule):
    layout = spread_layout(6)
    rng = np.random.default_rng(11)
    _, ents, _ = layout.split(rng.uniform(-0.6, 0.6, size=(3, 400, 6, layout.obs_dim)).astype(np.float32))
    ents = np.ascontiguousarray(ents)
    for keep in (0.0, 0.6, 1.0):
        mask = rng.random(ents.shape[:-1]) < 0.8
        mask[..., 6:] &= rng.random(mask[..., 6:].shape) < keep
        generic, twin = margins(ents, mask, rule)
        fast = holder_margin_of_slots(torch.from_numpy(ents), torch.from_numpy(mask), *holder_slots(layout),
                                      rule=rule).numpy()
        np.testing.assert_allclose(fast, generic, rtol=0, atol=1e-6)
        np.testing.assert_allclose(twin, generic, rtol=0, atol=1e-6)
    seated, nearest = margins(ents, mask, "seated")[0], margins(ents, mask, "nearest")[0]
    assert (seated >= nearest - 1e-6).all()  # fewer agents count: a margin only rises


def test_the_entity_actor_and_its_numpy_twin_act_alike_under_the_seated_rule():
    from cmcl.learners.maddpg import MADDPG
    from cmcl.learners.weights import published_weights
    from cmcl.rollout.policy import numpy_policy

    layout = spread_layout(5)
    maddpg = MADDPG(5, layout.obs_dim, seed=2, networks="entity", entity_layout=layout, entity_holder=True)
    for net in (maddpg.actor, maddpg.target_actor):
        net.holder_rule = "seated"
    obs = np.random.default_rng(1).uniform(-0.4, 0.4, size=(64, 5, layout.obs_dim)).astype(np.float32)
    weights = published_weights(maddpg)["actor"]
    twin = numpy_policy(weights, entities=layout, holder=True, holder_rule="seated")
    ours = maddpg.act(obs, 0.0)
    np.testing.assert_allclose(twin.act(obs, 0.0), ours, atol=1e-5)
    nearest = numpy_policy(weights, entities=layout, holder=True)
    assert not np.allclose(nearest.act(obs, 0.0), ours, atol=1e-5)
    with pytest.raises(ValueError, match="maddpg.holder_rule must be one of"):
        numpy_policy(weights, entities=layout, holder=True, holder_rule="first")


def test_an_unknown_rule_is_refused_not_read_as_nearest():
    v = view((0.5, 0.0, "l"), (0.6, 0.0, "a"))[None]
    with pytest.raises(ValueError, match="maddpg.holder_rule must be one of"):
        numpy_margin(v, np.ones((1, 2), bool), TYPES, "claimed")
    from cmcl.learners.entity.holder import with_holder
    with pytest.raises(ValueError, match="maddpg.holder_rule must be one of"):
        with_holder(torch.from_numpy(v), torch.ones(1, 2, dtype=torch.bool), TYPES, rule="claimed")


N8 = "configs/spread_n8.toml"
SEATED = "maddpg.holder_rule=seated"


@pytest.mark.parametrize("sets, message", [
    (["maddpg.entity_holder=false", SEATED], "maddpg.holder_rule needs maddpg.entity_holder = true"),
    ([SEATED, "env.cover_radius=0.075"], "maddpg.holder_rule needs env.cover_radius = 0.1"),
    (["maddpg.holder_rule=claimed"], "maddpg.holder_rule"),
])
def test_the_config_refuses_what_cannot_apply_in_one_line(sets, message):
    from cmcl.config import ConfigError, load_config

    with pytest.raises(ConfigError, match=message) as err:
        load_config(N8, sets)
    assert "\n" not in str(err.value)
    assert load_config(N8).maddpg.holder_rule == "nearest"


def test_every_service_role_reads_the_margin_by_the_rule():
    """The rollout worker's numpy actor, the learner's networks and their targets, the teachers and the entity ICM
    take the rule from the config, and one round of the data flow runs (tests/in_process.py)."""
    from tests.in_process import in_process_config, roles

    cfg = in_process_config("cmcl", maddpg={"networks": "entity", "entity_holder": True, "holder_rule": "seated"},
                            service={"score_rows_per_call": 360}, icm={"networks": "entity"},
                            teachers={"networks": "entity"})
    replay, learner, worker, teachers, icm = roles(cfg)
    for _ in range(3):
        replay.insert(worker.rollout(None)[0])
    nets = (learner.maddpg.actor, learner.maddpg.critic, learner.maddpg.target_actor, learner.maddpg.target_critic,
            icm.icm.phi, teachers[0].teachers.net, teachers[0].targets.target_critic)
    assert worker.policy.holder_rule == "seated" and {net.holder_rule for net in nets} == {"seated"}
    learner.update(replay.sample(4)[0])
    chunk, _ = worker.rollout(learner.publish())
    assert worker.policy.holder_rule == "seated" and np.isfinite(chunk.act).all()
    np.testing.assert_allclose(worker.policy.act(worker.obs, 0.0), learner.maddpg.act(worker.obs, 0.0), atol=1e-5)


def test_a_state_records_the_rule_a_resume_under_the_other_is_refused_and_a_warm_start_may_change_it():
    from cmcl.learners.maddpg import MADDPG
    from cmcl.run.warm_start import warm_start_

    layout = spread_layout(3)

    def build(rule: str) -> MADDPG:
        return MADDPG(3, layout.obs_dim, seed=0, networks="entity", entity_layout=layout, entity_holder=True,
                      holder_rule=rule)

    seated, nearest = build("seated").state_dict(), build("nearest").state_dict()
    assert seated["holder_rule"] == "seated"
    with pytest.raises(ValueError, match="^checkpoint maddpg without 'holder_rule': written by an older version"):
        build("nearest").load_state_dict({k: v for k, v in nearest.items() if k != "holder_rule"})
    with pytest.raises(ValueError) as err:
        build("nearest").load_state_dict(seated)
    assert str(err.value) == ("checkpoint maddpg was trained with maddpg.holder_rule = 'seated' and this config has "
                              "'nearest': the same weights would read another margin; set maddpg.holder_rule = "
                              "'seated'")
    learner = build("seated")
    warm_start_(learner, nearest, "runs/n8")
    assert learner.holder_rule == "seated"
    assert all(torch.equal(learner.actor.state_dict()[k], v) for k, v in nearest["actor"].items())


def test_it_trains_inline_and_evaluation_rebuilds_the_rule(tmp_path):
    from cmcl.config import load_config
    from cmcl.run.evaluate import load_policy
    from cmcl.run.rundir import RunDirectory
    from services.launch import train_in_process

    run = tmp_path / "run"
    config = load_config(N8, [SEATED, f"run.dir={run}", "run.init_from=", "run.episodes=32", "maddpg.warmup=480",
                              "maddpg.update_every=240", "run.max_seconds=0"])
    _, roles = train_in_process(config, RunDirectory.create(run, config))  # the inline runner
    maddpg = roles.learner.maddpg
    assert maddpg.updates > 0 and maddpg.actor.holder_rule == "seated"
    policy = RunDirectory.open(run).newest_policy()
    assert policy.state["maddpg"]["holder_rule"] == "seated"
    rebuilt = load_policy(RunDirectory.open(run).config(), policy)
    obs = np.random.default_rng(0).uniform(-0.5, 0.5, size=(8, 8, rebuilt.obs_dim)).astype(np.float32)
    np.testing.assert_array_equal(rebuilt.act(obs, 0.0), maddpg.act(obs, 0.0))
    with pytest.raises(ValueError, match="trained with maddpg.holder_rule = 'seated'"):
        load_policy(load_config(N8), policy)


def test_the_configs_holder_rules_are_the_learners_and_the_seated_radius_is_the_default_cover_radius():
    import typing

    from cmcl.config.learning import MADDPGConfig
    from cmcl.envs.params import SpreadParams
    from cmcl.learners.entity.holder_rules import HOLDER_RULES, SEATED_RADIUS

    hints = typing.get_type_hints(MADDPGConfig)
    assert typing.get_args(hints["holder_rule"]) == HOLDER_RULES
    assert SpreadParams().cover_radius == SEATED_RADIUS

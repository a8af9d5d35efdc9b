"""maddpg.holder_rule "claimed" (issue 38): an agent holds only the landmark it is nearest to, so a landmark that one
agent covers beside another (its second landmark) reads as held by nobody. Its values on hand-built views (torch,
the networks' slot path and the numpy twin), the three agreeing on random views, "nearest" unchanged, and the entity
actor and its numpy twin acting alike under it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from cmcl.envs.entities import spread_layout
from cmcl.learners.entity_holder import holder_margin, holder_margin_of_slots, holder_slots
from cmcl.learners.policy import HOLDER_ALONE
from cmcl.learners.policy import holder_margin as numpy_margin

TYPES = slice(2, 4)  # navigation's type one-hot (landmark, agent) after the 2 raw features


def view(*rows: tuple[float, float, str]) -> np.ndarray:
    """Entity rows [dx, dy, landmark, agent] float32[E, 4] from (dx, dy, "l" or "a")."""
    return np.array([[x, y, float(kind == "l"), float(kind == "a")] for x, y, kind in rows], np.float32)


def margins(entities: np.ndarray, mask: np.ndarray, rule: str) -> list[np.ndarray]:
    """The margin by the generic torch function and the numpy twin."""
    t = holder_margin(torch.from_numpy(entities), torch.from_numpy(mask), TYPES, rule).numpy()
    return [t, numpy_margin(entities, mask, TYPES, rule)]


def test_an_agent_on_two_landmarks_claims_only_its_nearest():
    # the viewer at the origin; landmarks A (0.5, 0) and B (0.5, 0.15); agent X at (0.5, 0.05) covers both (0.05 and
    # 0.1 away) and is nearest to A; agent Y at (-0.5, 0) is nearest to C (-0.6, 0)
    v = view((0.5, 0.0, "l"), (0.5, 0.15, "l"), (-0.6, 0.0, "l"), (0.5, 0.05, "a"), (-0.5, 0.0, "a"))
    mask = np.ones((1, 5), bool)
    for out in margins(v[None], mask, "claimed"):
        np.testing.assert_allclose(out[0, :, 0], [0.05 - 0.5, HOLDER_ALONE, 0.1 - 0.6, 0, 0], atol=1e-6)
    for out in margins(v[None], mask, "nearest"):  # the old rule: X holds B too
        np.testing.assert_allclose(out[0, :, 0], [0.05 - 0.5, 0.1 - np.hypot(0.5, 0.15), 0.1 - 0.6, 0, 0],
                                   atol=1e-6)


def test_a_landmark_claimed_by_two_agents_reads_the_nearer_and_absent_entities_take_no_part():
    v = view((0.5, 0.0, "l"), (0.9, 0.0, "l"), (0.55, 0.0, "a"), (0.45, 0.0, "a"), (0.9, 0.05, "a"))
    mask = np.array([[True, True, True, True, True], [True, True, True, True, False], [True, False, True, True, True]])
    for out in margins(np.stack([v] * 3), mask, "claimed"):
        np.testing.assert_allclose(out[0, :2, 0], [0.05 - 0.5, 0.05 - 0.9], atol=1e-6)
        np.testing.assert_allclose(out[1, :2, 0], [0.05 - 0.5, HOLDER_ALONE], atol=1e-6)  # its claimer absent
        # landmark 1 absent: the third agent claims landmark 0 instead (its only present one), still not the nearest
        np.testing.assert_allclose(out[2, :2, 0], [0.05 - 0.5, 0.0], atol=1e-6)


@pytest.mark.parametrize("rule", ["nearest", "claimed"])
def test_the_slot_path_the_generic_path_and_the_numpy_twin_agree_on_random_views(rule):
    layout = spread_layout(6)
    rng = np.random.default_rng(11)
    _, ents, _ = layout.split(rng.uniform(-1.5, 1.5, size=(3, 40, 6, layout.obs_dim)).astype(np.float32))
    ents = np.ascontiguousarray(ents)
    for keep in (0.0, 0.6, 1.0):
        mask = rng.random(ents.shape[:-1]) < 0.8
        mask[..., 6:] &= rng.random(mask[..., 6:].shape) < keep
        generic, twin = margins(ents, mask, rule)
        fast = holder_margin_of_slots(torch.from_numpy(ents), torch.from_numpy(mask), *holder_slots(layout),
                                      rule=rule).numpy()
        np.testing.assert_allclose(fast, generic, rtol=0, atol=1e-6)
        np.testing.assert_allclose(twin, generic, rtol=0, atol=1e-6)
    claimed, nearest = margins(ents, mask, "claimed")[0], margins(ents, mask, "nearest")[0]
    assert (claimed >= nearest - 1e-6).all()  # fewer agents count: a margin only rises
    assert (claimed > nearest + 1e-6).mean() > 0.05  # and on random views it often does


def test_the_entity_actor_and_its_numpy_twin_act_alike_under_the_claimed_rule():
    from cmcl.learners.maddpg import MADDPG
    from cmcl.learners.policy import numpy_policy
    from cmcl.learners.weights import published_weights

    layout = spread_layout(5)
    maddpg = MADDPG(5, layout.obs_dim, seed=2, networks="entity", entity_layout=layout, entity_holder=True)
    for net in (maddpg.actor, maddpg.target_actor):
        net.holder_rule = "claimed"
    obs = np.random.default_rng(1).uniform(-1, 1, size=(7, 5, layout.obs_dim)).astype(np.float32)
    weights = published_weights(maddpg)["actor"]
    twin = numpy_policy(weights, entities=layout, holder=True, holder_rule="claimed")
    ours = maddpg.act(obs, 0.0)
    np.testing.assert_allclose(twin.act(obs, 0.0), ours, atol=1e-5)
    nearest = numpy_policy(weights, entities=layout, holder=True)
    assert not np.allclose(nearest.act(obs, 0.0), ours, atol=1e-5)
    with pytest.raises(ValueError, match="maddpg.holder_rule must be one of"):
        numpy_policy(weights, entities=layout, holder=True, holder_rule="first")

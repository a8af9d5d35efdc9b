"""The PettingZoo envs: PettingZoo's own conformance tests, spaces, rendering with walls, bad input."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from mpe2._mpe_utils.core import World

from cmcl.envs import sparse_spread_v0, sparse_tag_v0

with warnings.catch_warnings():  # pettingzoo.test imports its example envs through a deprecated path
    warnings.simplefilter("ignore", DeprecationWarning)
    from pettingzoo.test import parallel_api_test, parallel_seed_test

MAKERS = {
    "spread": sparse_spread_v0.parallel_env,
    "spread3": lambda **kw: sparse_spread_v0.parallel_env(num_agents=3, **kw),
    "spread3_tags": lambda **kw: sparse_spread_v0.parallel_env(num_agents=3, agent_tags=True, **kw),
    "tag": sparse_tag_v0.parallel_env,
    "tag3v1": lambda **kw: sparse_tag_v0.parallel_env(num_predators=3, num_prey=1, num_obstacles=2, **kw),
    "tag4v2_shared": lambda **kw: sparse_tag_v0.parallel_env(
        num_predators=4, predator_radius=0.075, prey_radius=0.05, shared_reward=True, **kw
    ),
}


@pytest.mark.parametrize("name", sorted(MAKERS))
def test_pettingzoo_conformance(name: str) -> None:
    parallel_api_test(MAKERS[name](), num_cycles=40)
    parallel_seed_test(MAKERS[name])


def test_spaces_names_and_world() -> None:
    spread = sparse_spread_v0.parallel_env()
    assert spread.possible_agents == [f"agent_{i}" for i in range(4)]
    assert isinstance(spread.unwrapped.world, World)
    space = spread.action_space("agent_0")
    assert space.shape == (2,) and space.dtype == np.float32 and space.low.min() == -1 and space.high.max() == 1
    assert spread.observation_space("agent_3").shape == (18,)
    tag = sparse_tag_v0.parallel_env()  # calibrated defaults (ALGORITHM.md §6.2): 2 predators, 2 prey, 3 obstacles
    assert tag.possible_agents == ["predator_0", "predator_1", "prey_0", "prey_1"]
    assert [tag.observation_space(a).shape[0] for a in tag.possible_agents] == [20] * 2 + [18] * 2
    assert [a.size for a in tag.world.agents] == [0.0375] * 2 + [0.025] * 2
    big = sparse_tag_v0.parallel_env(num_predators=4)
    assert [big.observation_space(a).shape[0] for a in big.possible_agents] == [24] * 4 + [22] * 2
    obs, infos = tag.reset(seed=3)
    assert all(obs[a].shape == tag.observation_space(a).shape and obs[a].dtype == np.float32 for a in obs)
    assert infos == {a: {} for a in tag.possible_agents}


@pytest.mark.parametrize("name", ["spread", "tag"])
def test_rgb_render_draws_the_walls(name: str) -> None:
    env = MAKERS[name](render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (400, 400, 3) and frame.dtype == np.uint8
    assert (frame[21, 100:300] < 60).all() and (frame[100:300, 378] < 60).all()  # top and right walls
    assert (frame[5, :] == 255).all()  # outside the arena: background
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 3  # discs drawn
    for _ in range(2):  # positions move with the previous velocity: the second step shows it
        env.step({a: np.ones(2, np.float32) for a in env.agents})
    assert not np.array_equal(env.render(), frame)
    with pytest.warns(UserWarning, match="render_mode"):
        assert MAKERS[name]().render() is None  # no render mode


@pytest.mark.parametrize(
    ("make", "kwargs", "pattern"),
    [
        (sparse_spread_v0.parallel_env, {"num_agents": 0}, "num_agents must be >= 1, got 0"),
        (sparse_spread_v0.parallel_env, {"max_cycles": 0}, "max_cycles must be >= 1, got 0"),
        (sparse_spread_v0.parallel_env, {"agent_radius": -0.05}, "agent_radius .* got -0.05"),
        (sparse_spread_v0.parallel_env, {"render_mode": "human"}, "render_mode .* got 'human'"),
        (sparse_tag_v0.parallel_env, {"num_prey": 0}, "num_prey must be >= 1, got 0"),
        (sparse_tag_v0.parallel_env, {"num_obstacles": -1}, "num_obstacles must be >= 0, got -1"),
        (sparse_tag_v0.parallel_env, {"prey_radius": -1.0}, "prey_radius .* got -1.0"),
    ],
)
def test_bad_constructor_values_raise(make, kwargs: dict, pattern: str) -> None:
    with pytest.raises(ValueError, match=pattern):
        make(**kwargs)


def test_bad_actions_raise() -> None:
    env = sparse_spread_v0.parallel_env()
    env.reset(seed=0)
    good = {a: np.zeros(2, np.float32) for a in env.agents}
    with pytest.raises(ValueError, match="missing agent 'agent_2'"):
        env.step({a: v for a, v in good.items() if a != "agent_2"})
    with pytest.raises(ValueError, match=r"agent_1 must have shape \(2,\)"):
        env.step({**good, "agent_1": np.zeros(3)})
    with pytest.raises(ValueError, match="agent_0 must be finite"):
        env.step({**good, "agent_0": np.array([np.nan, 0.0])})
    with pytest.raises(ValueError, match="agent_3 must be finite"):
        env.step({**good, "agent_3": np.array([0.0, np.inf])})
    with pytest.raises(ValueError, match="unknown agents"):
        env.step({**good, "agent_9": np.zeros(2)})
    assert env.steps == 0  # nothing was applied
    for _ in range(30):
        env.step(good)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(good)


def test_out_of_range_actions_are_clipped() -> None:
    a, b = sparse_tag_v0.parallel_env(), sparse_tag_v0.parallel_env()
    a.reset(seed=1)
    b.reset(seed=1)
    rng = np.random.default_rng(0)
    for _ in range(10):
        act = {n: rng.uniform(-1, 1, 2) * 4 for n in a.agents}
        oa = a.step(act)[0]
        ob = b.step({n: np.clip(v, -1, 1) for n, v in act.items()})[0]
        for n in oa:
            np.testing.assert_array_equal(oa[n], ob[n])

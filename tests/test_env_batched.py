"""The batched twins' interface: shapes, seeding, auto-reset, state, per-world independence and bad input."""

from __future__ import annotations

import numpy as np
import pytest

from cmcl.envs.batched import BatchedSparseSpread, BatchedSparseTag
from cmcl.envs.params import SpreadParams, TagParams


def _actions(rng: np.random.Generator, env, steps: int, scale: float = 1.0) -> np.ndarray:
    return rng.uniform(-scale, scale, (steps, env.num_envs, env.num_agents, env.act_dim)).astype(np.float32)


def test_default_layouts() -> None:
    spread = BatchedSparseSpread(3)
    assert (spread.num_agents, spread.obs_dim, spread.act_dim, spread.episode_length) == (4, 18, 2, 30)
    assert spread.obs_dims == (18,) * 4 and spread.teams == {"agent": [0, 1, 2, 3]}
    tag = BatchedSparseTag(3)  # calibrated defaults (ALGORITHM.md §6.2): 2 predators, 2 prey, 3 obstacles
    assert (tag.num_agents, tag.obs_dim) == (4, 20) and tag.obs_dims == (20,) * 2 + (18,) * 2
    assert tag.teams == {"predator": [0, 1], "prey": [2, 3]}
    for env in (spread, tag):
        obs = env.reset(seed=0)
        assert obs.shape == (3, env.num_agents, env.obs_dim) and obs.dtype == np.float32
        obs, rew, dones, info = env.step(np.zeros((3, env.num_agents, 2), np.float32))
        assert rew.shape == (3, env.num_agents) and rew.dtype == np.float32
        assert dones.shape == (3,) and dones.dtype == bool and not dones.any()
        assert info["wall_hit"].shape == (3, env.num_agents) and info["episode_mask"].shape == (3,)
    assert not obs[:, 2:, 18:].any()  # prey rows are zero-padded past their true length


@pytest.mark.parametrize(
    ("cls", "params", "dims"),
    [
        (BatchedSparseSpread, SpreadParams(num_agents=1), (6,)),
        (BatchedSparseSpread, SpreadParams(num_agents=6), (26,) * 6),
        (BatchedSparseTag, TagParams(num_predators=3, num_prey=1, num_obstacles=2), (16,) * 3 + (14,)),
        (BatchedSparseTag, TagParams(num_predators=1, num_prey=3, num_obstacles=0), (16,) + (14,) * 3),
    ],
)
def test_other_sizes_run(cls, params: SpreadParams | TagParams, dims: tuple) -> None:
    env = cls(5, params, seed=1, dtype=np.float64)
    assert env.obs_dims == dims
    rng = np.random.default_rng(0)
    for a in _actions(rng, env, 30):
        obs, rew, dones, info = env.step(a)
        assert obs.dtype == np.float64 and np.isfinite(obs).all() and np.isfinite(rew).all()
    assert dones.all() and len(info["episode"]["return"]) == 5


@pytest.mark.parametrize("cls", [BatchedSparseSpread, BatchedSparseTag])
def test_seeding_is_reproducible(cls) -> None:
    def rollout(seed: int) -> np.ndarray:
        env = cls(4, seed=seed)
        rng = np.random.default_rng(0)
        return np.stack([env.step(a)[0] for a in _actions(rng, env, 10)])

    np.testing.assert_array_equal(rollout(3), rollout(3))
    assert not np.array_equal(rollout(3), rollout(4))
    env = cls(4, seed=3)
    first = env.reset(seed=11)
    env.step(np.zeros((4, env.num_agents, 2)))
    np.testing.assert_array_equal(env.reset(seed=11), first)


@pytest.mark.parametrize("cls", [BatchedSparseSpread, BatchedSparseTag])
def test_auto_reset_returns_first_obs_and_keeps_final_obs(cls) -> None:
    plain, auto = cls(6, seed=2), cls(6, seed=2, auto_reset=True)
    rng = np.random.default_rng(1)
    for t, a in enumerate(_actions(rng, plain, 30), start=1):
        p_obs, p_rew, p_done, p_info = plain.step(a)
        a_obs, a_rew, a_done, a_info = auto.step(a)
        np.testing.assert_array_equal(a_info["final_obs"], p_obs)
        np.testing.assert_array_equal(a_rew, p_rew)
        assert (a_done == p_done).all() and p_done.all() == (t == 30)
    for key, value in p_info["episode"].items():
        np.testing.assert_array_equal(a_info["episode"][key], value)
    state = auto.get_state()
    assert (state["step"] == 0).all() and not state["velocities"].any()
    assert not np.array_equal(a_obs, p_obs)  # new episodes started
    np.testing.assert_array_equal(a_obs, auto.observe())
    with pytest.raises(RuntimeError, match="reset"):
        plain.step(np.zeros((6, plain.num_agents, 2)))
    plain.reset()
    plain.step(np.zeros((6, plain.num_agents, 2)))


@pytest.mark.parametrize("cls", [BatchedSparseSpread, BatchedSparseTag])
def test_state_restores_the_future(cls) -> None:
    env = cls(4, seed=5)
    rng = np.random.default_rng(2)
    for a in _actions(rng, env, 12):
        env.step(a)
    saved = env.get_state()
    future = _actions(rng, env, 18)
    first = [env.step(a) for a in future]
    assert set(saved) >= {"positions", "velocities", "landmarks", "step"}
    assert saved["positions"].shape == (4, env.num_agents, 2) and saved["step"].dtype == np.int64
    env.set_state(saved)
    second = [env.step(a) for a in future]
    for (o1, r1, d1, _), (o2, r2, d2, _) in zip(first, second, strict=True):
        np.testing.assert_array_equal(o1, o2)
        np.testing.assert_array_equal(r1, r2)
        np.testing.assert_array_equal(d1, d2)
    assert first[-1][2].all()
    for key, value in first[-1][3]["episode"].items():  # the accumulators came back too
        np.testing.assert_array_equal(second[-1][3]["episode"][key], value)


@pytest.mark.parametrize("cls", [BatchedSparseSpread, BatchedSparseTag])
def test_worlds_are_independent(cls) -> None:
    big = cls(4, seed=8, dtype=np.float64)
    state = big.get_state()
    rng = np.random.default_rng(3)
    actions = _actions(rng, big, 30, scale=1.4)
    outs = [big.step(a) for a in actions]
    for k in (0, 3):
        one = cls(1, dtype=np.float64)
        one.set_state({key: value[k : k + 1] for key, value in state.items()})
        for a, (obs, rew, _, info) in zip(actions, outs, strict=True):
            o1, r1, _, i1 = one.step(a[k : k + 1])
            np.testing.assert_array_equal(o1[0], obs[k])
            np.testing.assert_array_equal(r1[0], rew[k])
            np.testing.assert_array_equal(i1["wall_hit"][0], info["wall_hit"][k])


def test_episode_info_covers_only_finished_worlds() -> None:
    env = BatchedSparseTag(4, seed=0, auto_reset=True)
    state = env.get_state()
    state["step"] = np.array([29, 3, 29, 10])
    env.set_state(state)
    _, _, dones, info = env.step(np.zeros((4, env.num_agents, 2)))
    np.testing.assert_array_equal(dones, [True, False, True, False])
    np.testing.assert_array_equal(info["episode_mask"], dones)
    assert all(len(v) == 2 for v in info["episode"].values())
    assert info["episode"]["return"].shape == (2, env.num_agents)
    np.testing.assert_array_equal(env.get_state()["step"], [0, 4, 0, 11])


def test_returned_arrays_are_not_internal_buffers() -> None:
    env = BatchedSparseSpread(1, seed=0)
    obs0, rew0, _, info0 = env.step(np.ones((1, 4, 2)))
    keep_obs, keep_rew, keep_hit = obs0.copy(), rew0.copy(), info0["wall_hit"].copy()
    obs0[...] = 99.0
    env.step(-np.ones((1, 4, 2)))
    env.step(np.ones((1, 4, 2)))
    np.testing.assert_array_equal(rew0, keep_rew)
    np.testing.assert_array_equal(info0["wall_hit"], keep_hit)
    assert not np.array_equal(env.observe(), obs0) and not np.array_equal(keep_obs, obs0)


@pytest.mark.parametrize("cls", [BatchedSparseSpread, BatchedSparseTag])
def test_out_of_range_actions_are_clipped(cls) -> None:
    a, b = cls(3, seed=4), cls(3, seed=4)
    rng = np.random.default_rng(5)
    for act in _actions(rng, a, 10, scale=1.0):
        big = np.where(np.abs(act) > 0.9, np.sign(act) * 7.5, act)
        clipped = np.clip(big, -1, 1)
        np.testing.assert_array_equal(a.step(big)[0], b.step(clipped)[0])


@pytest.mark.parametrize("cls", [BatchedSparseSpread, BatchedSparseTag])
@pytest.mark.parametrize(
    ("bad", "message"),
    [
        (np.zeros((2, 3)), "shape"),
        ("nan", "finite"),
        ("inf", "finite"),
        (np.array([["a"]]), "shape"),
    ],
)
def test_bad_actions_raise(cls, bad, message: str) -> None:
    env = cls(2, seed=0)
    if isinstance(bad, str):
        arr = np.zeros((2, env.num_agents, 2))
        arr[1, -1, 0] = np.nan if bad == "nan" else -np.inf
        bad = arr
    with pytest.raises(ValueError, match=message):
        env.step(bad)


@pytest.mark.parametrize(
    ("cls", "kwargs", "pattern"),
    [
        (BatchedSparseSpread, {"num_envs": 0}, "num_envs must be >= 1, got 0"),
        (BatchedSparseSpread, {"num_envs": 2, "episode_length": 0}, "episode_length must be >= 1, got 0"),
        (BatchedSparseSpread, {"num_envs": 2.5}, "num_envs .* got 2.5"),
        (BatchedSparseSpread, {"num_envs": 2, "dtype": np.int32}, "dtype"),
        (BatchedSparseTag, {"num_envs": 0}, "num_envs must be >= 1, got 0"),
    ],
)
def test_bad_constructor_values_raise(cls, kwargs: dict, pattern: str) -> None:
    with pytest.raises(ValueError, match=pattern):
        cls(**kwargs)


@pytest.mark.parametrize(
    ("params", "fields", "pattern"),
    [
        (SpreadParams, {"num_agents": 0}, "^num_agents must be >= 1, got 0"),
        (SpreadParams, {"agent_radius": -0.1}, "^agent_radius .* got -0.1"),
        (SpreadParams, {"agent_radius": 0.5}, "^agent_radius .* got 0.5"),  # no room inside the walls
        (SpreadParams, {"cover_radius": float("nan")}, "^cover_radius .* got nan"),
        (SpreadParams, {"cover_reward": float("inf")}, "^cover_reward .* got inf"),
        (TagParams, {"num_predators": 0}, "^num_predators must be >= 1, got 0"),
        (TagParams, {"num_prey": -1}, "^num_prey must be >= 1, got -1"),
        (TagParams, {"num_obstacles": -2}, "^num_obstacles must be >= 0, got -2"),
        (TagParams, {"obstacle_radius": -0.2}, "^obstacle_radius .* got -0.2"),
        (TagParams, {"prey_max_speed": 0.0}, "^prey_max_speed .* got 0.0"),
        (TagParams, {"obstacle_spawn": 0.5}, "^obstacle_spawn .* got 0.5"),
    ],
)
def test_bad_world_values_raise_naming_the_field(params: type, fields: dict, pattern: str) -> None:
    """The world's one home refuses a bad value; the message starts with the field's name (the config maps it to
    its TOML key)."""
    with pytest.raises(ValueError, match=pattern):
        params(**fields)


def test_bad_state_raises() -> None:
    env = BatchedSparseSpread(2, seed=0)
    state = env.get_state()
    with pytest.raises(ValueError, match="positions"):
        env.set_state({**state, "positions": state["positions"][:1]})
    with pytest.raises(ValueError, match="step"):
        env.set_state({**state, "step": np.array([0, 30])})
    with pytest.raises(ValueError, match="velocities"):
        env.set_state({k: v for k, v in state.items() if k != "velocities"})
    with pytest.raises(ValueError, match="finite"):
        env.set_state({**state, "landmarks": np.full_like(state["landmarks"], np.nan)})
    with pytest.raises(ValueError, match="unknown keys"):
        env.set_state({**state, "ep_captures": np.zeros(2, np.int64)})  # a predator-prey key
    with pytest.raises(ValueError, match="ep_return"):
        env.set_state({**state, "ep_return": np.zeros((2, 3))})

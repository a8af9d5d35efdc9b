"""Parity: the batched twins against the PettingZoo envs (mpe2's World.step plus walls).

Tolerance. mpe2 computes in float64, so the whole-episode parity runs the twins with
dtype=np.float64 and requires agreement to 1e-5 on positions, velocities, observations, rewards
and infos (observed: ~1e-13). float32 cannot hold 1e-5 over whole episodes: a contact force has
stiffness contact_force = 100, so a position error e becomes a velocity error ~100 * dt * e = 10 e
and, one step later, a position error ~2 e; each contact step roughly doubles the rounding error
(3e-8) and episodes with ~15 contact steps reach ~1e-3 (observed). The float32 twin is therefore
checked one step at a time, re-synchronised from the reference state before every step: one
step's rounding stays far below 1e-5, so that is the tolerance there.
"""

from __future__ import annotations

from functools import partial

import numpy as np
import pytest

from cmcl.envs import sparse_spread_v0, sparse_tag_v0
from cmcl.envs.batched import BatchedSparseSpread, BatchedSparseTag
from cmcl.envs.params import SpreadParams, TagParams
from cmcl.envs.state import get_world_state, set_world_state

TOL = 1e-5
# §6.2's first world with the shared D1 option: many more contacts, every predator paid per pair
TAG4V2_SHARED = {"num_predators": 4, "predator_radius": 0.075, "prey_radius": 0.05, "shared_reward": True}
TASKS = {
    "spread": (sparse_spread_v0.parallel_env, BatchedSparseSpread, ("wall_hit", "collided", "covering")),
    "spread_tags": (  # per-episode agent tags at the end of every observation (SpreadParams.agent_tags)
        partial(sparse_spread_v0.parallel_env, num_agents=3, agent_tags=True),
        partial(BatchedSparseSpread, params=SpreadParams(num_agents=3, agent_tags=True)),
        ("wall_hit", "collided", "covering"),
    ),
    "tag": (sparse_tag_v0.parallel_env, BatchedSparseTag, ("wall_hit", "captures")),
    "tag4v2_shared": (
        partial(sparse_tag_v0.parallel_env, **TAG4V2_SHARED),
        partial(BatchedSparseTag, params=TagParams(**TAG4V2_SHARED)),
        ("wall_hit", "captures"),
    ),
}


def _random_state(rng: np.random.Generator, pz, length: int) -> dict:
    """A B = 1 state anywhere in the arena: overlaps, high speeds and any step counter allowed."""
    n, num_l = len(pz.possible_agents), len(pz.world.landmarks)
    state = {
        "positions": rng.uniform(-0.47, 0.47, (1, n, 2)),
        "velocities": rng.uniform(-1.5, 1.5, (1, n, 2)),
        "landmarks": rng.uniform(-0.45, 0.45, (1, num_l, 2)),
        "step": rng.integers(0, length, 1),
    }
    if pz.episode_constants():  # a tagged world: new tags too
        state["tags"] = rng.uniform(0.0, 1.0, (1, n))
    return state


def _stack(states: list[dict]) -> dict:
    return {k: np.concatenate([s[k] for s in states]) for k in states[0]}


def _check_episode(pz_episode: dict, twin_episode: dict, pos: int) -> None:
    for key, value in pz_episode.items():
        np.testing.assert_allclose(twin_episode[key][pos], value, atol=TOL, err_msg=key)


@pytest.mark.parametrize("task", ["spread", "spread_tags", "tag", "tag4v2_shared"])
@pytest.mark.parametrize("round_seed", [0, 1, 2])
def test_float64_twin_matches_pettingzoo_over_whole_episodes(task: str, round_seed: int) -> None:
    make_pz, twin_cls, step_keys = TASKS[task]
    b, length = 8, 30
    rng = np.random.default_rng(100 + round_seed)
    envs = [make_pz() for _ in range(b)]
    for k, env in enumerate(envs):  # half natural starts, half arbitrary states mid-episode
        env.reset(seed=int(rng.integers(1 << 30)))
        if k % 2:
            set_world_state(env, _random_state(rng, env, length))
    twin = twin_cls(b, dtype=np.float64, auto_reset=True, seed=0)
    twin.set_state(_stack([get_world_state(e) for e in envs]))
    names = envs[0].possible_agents
    live = np.ones(b, dtype=bool)
    while live.any():
        actions = rng.uniform(-1.5, 1.5, (b, len(names), 2)).astype(np.float32)  # includes clipped values
        obs, rew, dones, info = twin.step(actions)
        next_obs = info["final_obs"]
        ended = np.flatnonzero(info["episode_mask"])
        state = twin.get_state()  # restarted worlds already hold their next episode: compare final_obs there
        for k in np.flatnonzero(live):
            p_obs, p_rew, p_term, p_trunc, p_info = envs[k].step({a: actions[k, i] for i, a in enumerate(names)})
            ref = get_world_state(envs[k])
            if not dones[k]:
                for key in ("positions", "velocities", "landmarks", "step"):
                    np.testing.assert_allclose(state[key][k], ref[key][0], atol=TOL, err_msg=key)
            for i, a in enumerate(names):
                dim = twin.obs_dims[i]
                np.testing.assert_allclose(next_obs[k, i, :dim], p_obs[a], atol=TOL)
                assert not next_obs[k, i, dim:].any()
                assert abs(rew[k, i] - p_rew[a]) <= TOL
                assert not p_term[a] and p_trunc[a] == bool(dones[k])
                for key in step_keys:
                    assert info[key][k, i] == p_info[a][key], key
                if task.startswith("spread"):
                    assert abs(info["reward_unshared"][k, i] - p_info[a]["reward_unshared"]) <= TOL
            if dones[k]:
                _check_episode(p_info[names[0]]["episode"], info["episode"], int(np.searchsorted(ended, k)))
                live[k] = False
            else:
                assert "episode" not in p_info[names[0]]


@pytest.mark.parametrize("task", ["spread", "spread_tags", "tag", "tag4v2_shared"])
def test_float32_twin_matches_one_step_from_reference_states(task: str) -> None:
    make_pz, twin_cls, step_keys = TASKS[task]
    b, length = 8, 30
    rng = np.random.default_rng(7)
    envs = [make_pz() for _ in range(b)]
    for env in envs:
        env.reset(seed=int(rng.integers(1 << 30)))
    twin = twin_cls(b, dtype=np.float32)
    names = envs[0].possible_agents
    worst = 0.0
    for _ in range(length):
        twin.set_state(_stack([get_world_state(e) for e in envs]))
        actions = rng.uniform(-1.2, 1.2, (b, len(names), 2)).astype(np.float32)
        obs, rew, dones, info = twin.step(actions)
        state = twin.get_state()
        for k, env in enumerate(envs):
            p_obs, p_rew, _, _, p_info = env.step({a: actions[k, i] for i, a in enumerate(names)})
            ref = get_world_state(env)
            for key in ("positions", "velocities"):
                err = np.abs(state[key][k] - ref[key][0]).max()
                worst = max(worst, err)
                assert err <= TOL, (key, err)
            for i, a in enumerate(names):
                np.testing.assert_allclose(obs[k, i, : twin.obs_dims[i]], p_obs[a], atol=TOL)
                assert rew[k, i] == p_rew[a]
                for key in step_keys:
                    assert info[key][k, i] == p_info[a][key]
    assert worst > 0.0  # float32 really differs from the float64 reference, yet stays within TOL per step


@pytest.mark.parametrize("task", ["spread", "spread_tags", "tag"])
def test_same_seed_gives_same_initial_state(task: str) -> None:
    make_pz, twin_cls, _ = TASKS[task]
    env = make_pz()
    obs, _ = env.reset(seed=123)
    twin = twin_cls(1, seed=123, dtype=np.float64)
    ref, got = get_world_state(env), twin.get_state()
    for key in ("positions", "velocities", "landmarks", "step", *(("tags",) if "tags" in ref else ())):
        np.testing.assert_array_equal(got[key], ref[key])
    twin_obs = twin.reset(seed=123)
    for i, a in enumerate(env.possible_agents):
        np.testing.assert_allclose(twin_obs[0, i, : twin.obs_dims[i]], obs[a], atol=TOL)


def test_state_round_trip_between_versions() -> None:
    env = sparse_tag_v0.parallel_env()
    env.reset(seed=5)
    for _ in range(7):
        env.step({a: env.action_space(a).sample() for a in env.agents})
    state = get_world_state(env)
    twin = BatchedSparseTag(1, dtype=np.float64)
    twin.set_state(state)
    back = twin.get_state()
    assert set(back) == set(state)
    for key, value in state.items():
        np.testing.assert_array_equal(back[key], value, err_msg=key)
    other = sparse_tag_v0.parallel_env()
    other.reset(seed=9)
    obs = set_world_state(other, back)
    assert other.steps == 7 and other.agents == other.possible_agents
    np.testing.assert_array_equal(obs["prey_1"], env.observe_all()["prey_1"])


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_coincident_agents_stay_finite_and_tie_break_to_the_lowest_index(dtype) -> None:
    """Two agents at one point (as when clamped into the same corner): no NaN, and agent 0 gets the cover."""
    env = sparse_spread_v0.parallel_env()
    env.reset(seed=3)
    state = get_world_state(env)
    state["landmarks"][0, 0] = [0.44, 0.44]
    state["positions"][0, :2] = [0.45, 0.45]  # both in the top-right corner, within 0.1 of landmark 0
    state["velocities"][0, :2] = 0.0
    set_world_state(env, state)
    twin = BatchedSparseSpread(1, dtype=dtype)
    twin.set_state(state)
    names = env.possible_agents
    rng = np.random.default_rng(0)
    covered_by_first = 0
    for _ in range(30):
        a = rng.uniform(-1, 1, (1, 4, 2)).astype(np.float32)
        a[0, :2] = [1.0, 1.0]  # both keep pushing into the corner
        _, p_rew, _, _, p_info = env.step({n: a[0, i] for i, n in enumerate(names)})
        _, rew, _, info = twin.step(a)
        ref = get_world_state(env)
        assert np.isfinite(ref["velocities"]).all() and np.isfinite(twin.get_state()["velocities"]).all()
        np.testing.assert_array_equal(ref["positions"][0, 0], ref["positions"][0, 1])
        for i, n in enumerate(names):
            assert info["covering"][0, i] == p_info[n]["covering"] and rew[0, i] == p_rew[n]
        assert not p_info["agent_1"]["covering"] and p_info["agent_0"]["collided"]
        covered_by_first += p_info["agent_0"]["covering"]
    assert covered_by_first == 30

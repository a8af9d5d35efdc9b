"""ALGORITHM.md §7 properties 28-33 (environments), each checked on the PettingZoo env and the batched twin."""

from __future__ import annotations

import numpy as np
import pytest

from cmcl.envs import sparse_spread_v0, sparse_tag_v0
from cmcl.envs.batched import BatchedSparseSpread, BatchedSparseTag
from cmcl.envs.params import EPISODE_LENGTH, SpreadParams, TagParams
from cmcl.envs.state import set_world_state

VERSIONS = ["pettingzoo", "twin"]
FAR = 0.35  # a corner position well away from the centre


def run(version: str, task: str, state: dict, actions: np.ndarray, **kwargs) -> list[dict]:
    """Step one world from `state` (B = 1 dict) with actions [T, N, 2]; per step: pos, vel, rew, info, done, episode."""
    out = []
    if version == "pettingzoo":
        env = (sparse_spread_v0 if task == "spread" else sparse_tag_v0).parallel_env(**kwargs)
        env.reset(seed=0)
        set_world_state(env, state)
        names = env.possible_agents
        for a in actions:
            _, rew, term, trunc, info = env.step({n: a[i] for i, n in enumerate(names)})
            world = env.world
            out.append(
                {
                    "pos": np.array([x.state.p_pos for x in world.agents]),
                    "vel": np.array([x.state.p_vel for x in world.agents]),
                    "rew": np.array([rew[n] for n in names]),
                    "info": {k: np.array([info[n][k] for n in names]) for k in info[names[0]] if k != "episode"},
                    "done": trunc[names[0]],
                    "terminated": any(term.values()),
                    "episode": info[names[0]].get("episode"),
                }
            )
        return out
    length = kwargs.pop("max_cycles", EPISODE_LENGTH)  # the PettingZoo env's keywords: max_cycles and the world's
    twin, params = (BatchedSparseSpread, SpreadParams) if task == "spread" else (BatchedSparseTag, TagParams)
    env = twin(1, params(**kwargs), episode_length=length)
    env.set_state(state)
    for a in actions:
        _, rew, done, info = env.step(a[None].astype(np.float32))
        st = env.get_state()
        episode = {k: v[0] for k, v in info["episode"].items()} if done[0] else None
        steps = {k: v[0] for k, v in info.items() if k not in ("episode", "episode_mask", "final_obs")}
        out.append(
            {
                "pos": st["positions"][0],
                "vel": st["velocities"][0],
                "rew": rew[0],
                "info": steps,
                "done": bool(done[0]),
                "terminated": False,
                "episode": episode,
            }
        )
    return out


def state(pos, landmarks, vel=None, step=0) -> dict:
    pos = np.asarray(pos, dtype=np.float64)
    return {
        "positions": pos[None],
        "velocities": (np.zeros_like(pos) if vel is None else np.asarray(vel, dtype=np.float64))[None],
        "landmarks": np.asarray(landmarks, dtype=np.float64).reshape(1, -1, 2),
        "step": np.array([step]),
    }


# ----- 28: walls ------------------------------------------------------------------------------
@pytest.mark.parametrize("version", VERSIONS)
@pytest.mark.parametrize("task", ["spread", "tag"])
def test_28_wall_clamp_zeroes_velocity_and_penalises_exactly_when_it_fires(version: str, task: str) -> None:
    rng = np.random.default_rng(28)
    if task == "spread":  # one agent, its landmark far away in the centre: only walls can cost reward
        kwargs, st, radius = {"num_agents": 1}, state([[0.3, -0.3]], [[0.0, 0.0]], vel=[[1.0, -0.5]]), 0.05
        kwargs["cover_radius"] = 0.01
    else:  # one predator and one prey in opposite corners, no obstacles
        kwargs = {"num_predators": 1, "num_prey": 1, "num_obstacles": 0}
        st, radius = state([[-0.3, -0.3], [0.3, 0.3]], np.zeros((0, 2)), vel=[[-1.0, 0.0], [1.5, 1.0]]), None
    n = st["positions"].shape[1]
    actions = np.sign(st["positions"][0])[None] * rng.uniform(0.2, 1.5, (30, n, 2))  # push outwards
    radii = np.array([radius]) if radius else TagParams(**kwargs).radii
    prev_pos, prev_vel = st["positions"][0], st["velocities"][0]
    fired_any = quiet_any = False
    for s in run(version, task, st, actions, **kwargs):
        limit = (0.5 - radii[:, None]).astype(s["pos"].dtype)  # [N, 1], in the version's precision
        predicted = np.abs(prev_pos + prev_vel * 0.1) > limit  # [N, 2]: mpe2 moves with the old velocity
        assert (np.abs(s["pos"]) <= limit + 1e-7).all()
        assert (s["vel"][predicted] == 0.0).all()
        hit = predicted.any(axis=1)
        np.testing.assert_array_equal(s["info"]["wall_hit"], hit)
        rewards = s["info"].get("reward_unshared", s["rew"])
        np.testing.assert_array_equal(rewards, np.where(hit, -1.0, 0.0))
        fired_any |= hit.any()
        quiet_any |= (~hit).any()
        prev_pos, prev_vel = s["pos"], s["vel"]
    assert fired_any and quiet_any


# ----- 29, 30: navigation rewards -------------------------------------------------------------
@pytest.mark.parametrize("version", VERSIONS)
def test_29_two_agents_on_one_landmark_earn_four_in_total(version: str) -> None:
    lms = [[0.0, 0.0], [FAR, FAR], [-FAR, FAR], [FAR, -FAR]]
    pos = [[0.06, 0.0], [-0.06, 0.0], [-FAR, -FAR], [-FAR, 0.0]]  # 0.12 apart: no contact, both within 0.1
    s = run(version, "spread", state(pos, lms), np.zeros((1, 4, 2)), shared_reward=False)[0]
    assert s["rew"].sum() == 4.0
    assert sorted(s["rew"]) == [0.0, 0.0, 0.0, 4.0]


@pytest.mark.parametrize("version", VERSIONS)
def test_29_one_agent_per_landmark_earns_sixteen_and_succeeds(version: str) -> None:
    lms = [[0.2, 0.2], [-0.2, 0.2], [0.2, -0.2], [-0.2, -0.2]]
    pos = np.array(lms) + 0.03
    steps = run(version, "spread", state(pos, lms, step=29), np.zeros((1, 4, 2)), shared_reward=False)
    s = steps[0]
    assert s["rew"].sum() == 16.0
    assert s["done"] and s["episode"]["success"] and s["episode"]["coverage"] == 1.0
    shared = run(version, "spread", state(pos, lms, step=29), np.zeros((1, 4, 2)))[0]
    np.testing.assert_array_equal(shared["rew"], [16.0] * 4)  # shared: every agent gets the team sum


@pytest.mark.parametrize("version", VERSIONS)
def test_30_single_agent_away_from_walls_gets_zero(version: str) -> None:
    rng = np.random.default_rng(30)
    actions = rng.uniform(-0.3, 0.3, (20, 1, 2))
    for s in run(version, "spread", state([[0.0, 0.0]], [[FAR, FAR]]), actions, num_agents=1):
        assert not s["info"]["wall_hit"].any()
        assert s["rew"][0] == 0.0


# ----- 31: predator-prey rewards and speeds ---------------------------------------------------
# §6.2's first world (4 predators of radius 0.075, 2 prey of radius 0.05: capture below 0.125), given
# explicitly so that the geometry below does not depend on the calibrated defaults.
TAG4V2 = {"num_predators": 4, "num_prey": 2, "predator_radius": 0.075, "prey_radius": 0.05}
OBSTACLES = [[0.0, 0.1], [-0.3, 0.2], [0.2, 0.2]]


def _tag_state(touching: bool, second: bool = False) -> dict:
    """Predator 0 and prey 0 0.1 apart if `touching` (0.4 otherwise); with `second` predator 1 also 0.1 from prey 0."""
    pos = [[-0.2, -0.2], [FAR, -FAR], [-FAR, FAR], [FAR, 0.0], [-0.1 if touching else 0.2, -0.2], [0.0, FAR]]
    if second:
        pos[1] = [-0.1, -0.1]  # 0.1 from prey 0 (and 0.141 from predator 0: a push, no reward)
    return state(pos, OBSTACLES)


@pytest.mark.parametrize("version", VERSIONS)
def test_31_contact_pays_that_predator_and_charges_that_prey(version: str) -> None:
    # positions after the first step are the initial ones (mpe2 moves with the old, zero, velocity)
    s = run(version, "tag", _tag_state(True), np.zeros((1, 6, 2)), **TAG4V2)[0]
    np.testing.assert_array_equal(s["rew"], [5.0, 0.0, 0.0, 0.0, -5.0, 0.0])
    np.testing.assert_array_equal(s["info"]["captures"], [1, 0, 0, 0, 1, 0])
    both = run(version, "tag", _tag_state(True, second=True), np.zeros((1, 6, 2)), **TAG4V2)[0]
    np.testing.assert_array_equal(both["rew"], [5.0, 5.0, 0.0, 0.0, -10.0, 0.0])  # one +5 per pair, -5 per pair
    np.testing.assert_array_equal(both["info"]["captures"], [1, 1, 0, 0, 2, 0])
    quiet = run(version, "tag", _tag_state(False), np.zeros((3, 6, 2)), **TAG4V2)
    for s in quiet:
        np.testing.assert_array_equal(s["rew"], np.zeros(6))


@pytest.mark.parametrize("version", VERSIONS)
def test_31_shared_option_pays_every_predator_per_pair(version: str) -> None:
    kwargs = {**TAG4V2, "shared_reward": True}
    s = run(version, "tag", _tag_state(True), np.zeros((1, 6, 2)), **kwargs)[0]
    np.testing.assert_array_equal(s["rew"], [5.0, 5.0, 5.0, 5.0, -5.0, 0.0])
    np.testing.assert_array_equal(s["info"]["captures"], [1, 0, 0, 0, 1, 0])
    both = run(version, "tag", _tag_state(True, second=True), np.zeros((1, 6, 2)), **kwargs)[0]
    np.testing.assert_array_equal(both["rew"], [10.0, 10.0, 10.0, 10.0, -10.0, 0.0])
    for s in run(version, "tag", _tag_state(False), np.zeros((3, 6, 2)), **kwargs):
        np.testing.assert_array_equal(s["rew"], np.zeros(6))


@pytest.mark.parametrize("version", VERSIONS)
@pytest.mark.parametrize(("gap", "caught"), [(0.06, True), (0.065, False)])
def test_31_default_capture_distance_is_the_sum_of_the_radii(version: str, gap: float, caught: bool) -> None:
    """Defaults (2 v 2, radii 0.0375 / 0.025): a pair is in contact below 0.0625."""
    pos = [[-0.2, -0.2], [FAR, -FAR], [-0.2 + gap, -0.2], [0.0, FAR]]
    s = run(version, "tag", state(pos, OBSTACLES), np.zeros((1, 4, 2)))[0]
    np.testing.assert_array_equal(s["rew"], [5.0, 0.0, -5.0, 0.0] if caught else np.zeros(4))
    np.testing.assert_array_equal(s["info"]["captures"], [1, 0, 1, 0] if caught else np.zeros(4))


@pytest.mark.parametrize("version", VERSIONS)
def test_31_prey_top_speed_is_twice_the_predators(version: str) -> None:
    kwargs = {"num_predators": 1, "num_prey": 1, "num_obstacles": 0}
    st = state([[-0.3, -0.3], [-0.3, 0.3]], np.zeros((0, 2)), vel=[[3.0, 0.0], [3.0, 0.0]])  # fast, walls far
    s = run(version, "tag", st, np.array([[[1.0, 0.0], [1.0, 0.0]]]), **kwargs)[0]
    assert not s["info"]["wall_hit"].any()  # unclamped: 3 * 0.75 + accel * 0.1 = 2.55 and 2.65
    np.testing.assert_allclose(np.linalg.norm(s["vel"], axis=1), [1.0, 2.0], rtol=1e-6)
    default = BatchedSparseTag(1)
    np.testing.assert_array_equal(default.params.max_speeds, [1.0] * 2 + [2.0] * 2)
    pz = sparse_tag_v0.parallel_env()
    assert [a.max_speed for a in pz.world.agents] == [1.0] * 2 + [2.0] * 2


def test_31_tag_defaults_agree_everywhere() -> None:
    """TagParams, both env classes and EnvConfig (through make_batched_env / make_parallel_env) share the defaults."""
    from cmcl.config import EnvConfig, config_from_dict, preset
    from cmcl.system import make_batched_env, make_parallel_env

    calibrated = TagParams(num_predators=2, num_prey=2, num_obstacles=3, predator_radius=0.0375, prey_radius=0.025,
                           obstacle_radius=0.1, shared_reward=False)
    assert TagParams() == calibrated
    assert BatchedSparseTag(1).params == calibrated and sparse_tag_v0.parallel_env().params == calibrated
    assert EnvConfig().tag == calibrated
    config = preset("maddpg", "tag")
    assert make_batched_env(config, num_envs=1).params == calibrated
    assert make_parallel_env(config).params == calibrated
    data = config.to_dict()
    shared = config_from_dict({**data, "env": {**data["env"], "tag_shared_reward": True}})  # the TOML key
    assert make_batched_env(shared, num_envs=1).params.shared_reward
    assert make_parallel_env(shared).params.shared_reward


# ----- 32: metrics ----------------------------------------------------------------------------
@pytest.mark.parametrize("version", VERSIONS)
def test_32_cover_rate_is_taken_at_the_final_step(version: str) -> None:
    lms = [[0.2, 0.2], [-0.2, 0.2], [0.2, -0.2], [-0.2, -0.2]]
    leave = np.zeros((3, 4, 2))
    leave[:, 0] = [1.0, 1.0]  # agent 0 drives off its landmark (offsets 0, 0.05, 0.1375 per axis); the others stay
    steps = run(version, "spread", state(lms, lms, step=27), leave)
    assert [s["info"]["covering"][0] for s in steps] == [True, True, False]
    assert not steps[1]["done"] and steps[1]["episode"] is None
    assert steps[2]["done"] and steps[2]["episode"]["coverage"] == 0.75  # only the final step counts
    assert not steps[2]["episode"]["success"]
    assert steps[2]["episode"]["coverage_mean"] == pytest.approx((1.0 + 1.0 + 0.75) / 3)


@pytest.mark.parametrize("version", VERSIONS)
def test_32_predator_win_iff_a_capture_happened(version: str) -> None:
    flee = np.zeros((3, 6, 2))
    flee[:, 4] = [1.0, 0.0]  # prey 0 runs away after the first contact
    won = run(version, "tag", {**_tag_state(True), "step": np.array([27])}, flee, **TAG4V2)
    assert won[0]["info"]["captures"][4] == 1 and won[-1]["info"]["captures"][4] == 0
    assert won[-1]["done"] and won[-1]["episode"]["predator_win"] and won[-1]["episode"]["captures"] >= 1
    lost = run(version, "tag", {**_tag_state(False), "step": np.array([27])}, np.zeros((3, 6, 2)), **TAG4V2)
    assert lost[-1]["done"] and not lost[-1]["episode"]["predator_win"] and lost[-1]["episode"]["captures"] == 0


# ----- 33: fixed episode length, no terminal states -------------------------------------------
@pytest.mark.parametrize("version", VERSIONS)
@pytest.mark.parametrize("task", ["spread", "tag"])
def test_33_episodes_last_thirty_steps_and_never_terminate(version: str, task: str) -> None:
    rng = np.random.default_rng(33)
    if version == "pettingzoo":
        env = (sparse_spread_v0 if task == "spread" else sparse_tag_v0).parallel_env()
        for episode in range(2):
            env.reset(seed=episode)
            length = 0
            while env.agents:
                _, _, term, trunc, _ = env.step({a: rng.uniform(-1, 1, 2) for a in env.agents})
                length += 1
                assert not any(term.values())
                assert all(trunc.values()) == (length == 30)
            assert length == 30
    else:
        env = (BatchedSparseSpread if task == "spread" else BatchedSparseTag)(4, seed=1, auto_reset=True)
        for t in range(1, 61):
            _, _, dones, info = env.step(rng.uniform(-1, 1, (4, env.num_agents, 2)))
            assert dones.all() == (t % 30 == 0) and dones.any() == dones.all()
            assert len(info["episode"]["return"]) == (4 if t % 30 == 0 else 0)

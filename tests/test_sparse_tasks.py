"""The sparse tasks: VACL's all-or-nothing and SPMARL's gated navigation (cmcl.envs.sparse_nav, its
ParallelEnv cmcl.envs.sparse_nav_v0 and batched twin), CMAE's Push-Box and Pass (cmcl.envs.cmae_grids), their
presets and the sparse_calibration grid.

Rules are checked on hand-built states; the navigation ParallelEnv and its float64 twin agree on whole episodes from
the same seeds and actions (tolerance as tests/test_env_parity.py: 1e-5, observed ~1e-13).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cmcl.config import load_data
from cmcl.envs.cmae_grids import DOWN, LEFT, RIGHT, STAY, UP, PassEnv, PushBoxEnv, pass_env, push_box_env
from cmcl.envs.factory import describe, load_factory
from cmcl.envs.sparse_nav import BatchedSparseNav, NavParams, variant
from cmcl.envs.sparse_nav_v0 import parallel_env
from cmcl.envs.state import get_world_state, set_world_state

ROOT = Path(__file__).resolve().parents[1]
TOL = 1e-5
NAV = {"vacl_n4": ("vacl", 4), "vacl_n8": ("vacl", 8), "spmarl_n8": ("spmarl", 8)}
PRESETS = ("vacl_n4", "vacl_n8", "spmarl_n8", "push_box", "pass")


def _place(env, agents, landmarks, velocities=None):
    agents, landmarks = np.asarray(agents, float), np.asarray(landmarks, float)
    vel = np.zeros_like(agents) if velocities is None else np.asarray(velocities, float)
    return set_world_state(env, {"positions": agents[None], "velocities": vel[None], "landmarks": landmarks[None],
                                 "step": np.array([0])})


def _still(env):
    return {a: np.zeros(2) for a in env.possible_agents}


# ----- navigation: rules ----------------------------------------------------------------------------------------
def test_vacl_pays_the_team_only_when_every_landmark_is_covered_and_penalises_contact():
    env = parallel_env("vacl", num_agents=4)
    env.reset(seed=0)
    far = np.array([[-2.0, -2.0], [-1.0, -2.0], [0.0, -2.0], [1.0, -2.0]])
    lms = far + np.array([0.1, 0.0])  # each within 0.15 of its agent
    _place(env, far, lms)
    _, rew, term, trunc, info = env.step(_still(env))
    assert all(r == pytest.approx(0.4) for r in rew.values())
    assert info["agent_0"]["success"] and info["agent_0"]["coverage"] == 1.0
    assert not any(term.values()) and not any(trunc.values())
    lms[3] = [2.5, 2.5]  # one landmark left uncovered: nothing at all
    _place(env, far, lms)
    _, rew, _, _, info = env.step(_still(env))
    assert all(r == 0.0 for r in rew.values()) and not info["agent_0"]["success"]
    assert info["agent_0"]["coverage"] == 0.75
    touching = far.copy()
    touching[1] = touching[0] + [0.15, 0.0]  # agents 0 and 1 in contact (0.15 < 0.1 + 0.1)
    _place(env, touching, far + [0.1, 0.0])
    _, rew, _, _, info = env.step(_still(env))
    assert info["agent_0"]["collided"] and info["agent_1"]["collided"] and not info["agent_2"]["collided"]
    assert rew["agent_2"] == pytest.approx(0.0 if not info["agent_2"]["success"] else 0.4)
    assert rew["agent_0"] == pytest.approx(rew["agent_2"] - 0.1)


def test_vacl_observation_carries_each_landmark_covered_bit():
    env = parallel_env("vacl", num_agents=4)
    env.reset(seed=0)
    agents = np.array([[-2.0, -2.0], [-1.0, -2.0], [0.0, -2.0], [1.0, -2.0]])
    lms = np.array([[-2.0, -1.9], [2.0, 2.0], [0.0, -2.1], [-2.5, 2.5]])
    obs = _place(env, agents, lms)
    o = obs["agent_3"]
    assert o.shape == (22,)
    assert [o[4 + 3 * l] for l in range(4)] == [1.0, 0.0, 1.0, 0.0]
    np.testing.assert_allclose(o[5:7], lms[0] - agents[3], atol=1e-6)
    np.testing.assert_allclose(o[4 + 12 :], (agents[[0, 1, 2]] - agents[3]).ravel(), atol=1e-6)


def test_spmarl_counts_covered_landmarks_only_from_four_on():
    env = parallel_env("spmarl", num_agents=8)
    env.reset(seed=0)
    agents = np.array([[x, -1.5] for x in np.linspace(-1.6, 1.6, 8)])  # 0.46 apart: no contact
    for covered in (0, 3, 4, 7, 8):
        lms = np.array([[x, 1.5] for x in np.linspace(-1.6, 1.6, 8)])
        lms[:covered] = agents[:covered] + [0.0, 0.12]  # within 0.13
        _place(env, agents, lms)
        _, rew, _, _, info = env.step(_still(env))
        want = float(covered) if covered >= 4 else 0.0
        assert all(r == pytest.approx(want) for r in rew.values()), covered
        assert info["agent_0"]["covered"] == covered and info["agent_0"]["success"] == (covered == 8)
    lms[0] = agents[0] + [0.0, 0.14]  # just outside 0.13
    _place(env, agents, lms)
    assert env.step(_still(env))[4]["agent_0"]["covered"] == 7
    agents[1] = agents[0] + [0.2, 0.0]  # contact (0.2 < 0.3): no penalty in SPMARL
    _place(env, agents, lms)
    _, rew, _, _, info = env.step(_still(env))
    assert info["agent_0"]["collided"] and rew["agent_0"] == rew["agent_5"]


@pytest.mark.parametrize("task", list(NAV))
def test_navigation_episodes_last_their_length_and_report_final_step_success(task):
    name, n = NAV[task]
    env = parallel_env(name, num_agents=n)
    p = env.params
    assert p.episode_length == (70 if name == "vacl" else 25)
    env.reset(seed=1)
    agents = np.array([[x, 0.0] for x in np.linspace(-1.4, 1.4, n)])
    _place(env, agents, agents + [0.05, 0.0])
    for t in range(p.episode_length):
        _, _, term, trunc, info = env.step(_still(env))
        assert not any(term.values()) and all(trunc.values()) == (t == p.episode_length - 1)
    assert info["agent_0"]["episode"]["success"] and info["agent_0"]["success"]
    assert not env.agents


def test_the_variants_hold_the_sources_numbers():
    vacl, spmarl = variant("vacl"), variant("spmarl")
    assert (vacl.agent_radius, vacl.cover_radius, vacl.agent_spawn, vacl.landmark_spawn) == (0.1, 0.15, 3.0, 3.0)
    assert (vacl.cover_reward, vacl.collision_reward, vacl.episode_length, vacl.cover_bits) == (0.4, -0.1, 70, True)
    assert (spmarl.num_agents, spmarl.agent_radius, spmarl.cover_radius) == (8, 0.15, 0.13)
    assert (spmarl.agent_spawn, spmarl.landmark_spawn, spmarl.gate, spmarl.episode_length) == (2.0, 1.6, 4, 25)
    env = parallel_env("spmarl")
    env.reset(seed=3)
    s = get_world_state(env)
    assert np.abs(s["positions"]).max() <= 2.0 and np.abs(s["landmarks"]).max() <= 1.6
    with pytest.raises(ValueError, match="rule"):
        NavParams(rule="dense")


# ----- navigation: parity with the twin ---------------------------------------------------------------------------
@pytest.mark.parametrize("task", list(NAV))
@pytest.mark.parametrize("round_seed", [0, 1])
def test_float64_twin_matches_the_parallel_env_over_whole_episodes(task, round_seed):
    name, n = NAV[task]
    b = 4
    rng = np.random.default_rng(10 + round_seed)
    envs = [parallel_env(name, num_agents=n) for _ in range(b)]
    seeds = [int(rng.integers(1 << 30)) for _ in range(b)]
    for env, seed in zip(envs, seeds, strict=True):
        env.reset(seed=seed)
    p = envs[0].params
    twin = BatchedSparseNav(1, p, dtype=np.float64)  # the same seed gives the same first state
    for env, seed in zip(envs, seeds, strict=True):
        np.testing.assert_allclose(twin.reset(seed=seed)[0, 0], env.observe_all()["agent_0"], atol=TOL)
    for k in range(1, b, 2):  # half from crowded states: agents packed around the landmarks, moving
        state = get_world_state(envs[k])
        state["positions"] = state["landmarks"] + rng.uniform(-0.15, 0.15, state["positions"].shape)
        state["velocities"] = rng.uniform(-1.0, 1.0, state["positions"].shape)
        set_world_state(envs[k], state)
    twin = BatchedSparseNav(b, p, dtype=np.float64, auto_reset=True, seed=0)
    twin.set_state({k: np.concatenate([get_world_state(e)[k] for e in envs]) for k in get_world_state(envs[0])})
    names = envs[0].possible_agents
    for _ in range(p.episode_length):
        actions = rng.uniform(-1.5, 1.5, (b, n, 2))
        _, rew, dones, info = twin.step(actions)
        for k, env in enumerate(envs):
            p_obs, p_rew, _, p_trunc, p_info = env.step({a: actions[k, i] for i, a in enumerate(names)})
            for i, a in enumerate(names):
                np.testing.assert_allclose(info["final_obs"][k, i], p_obs[a], atol=TOL)
                assert abs(rew[k, i] - p_rew[a]) <= TOL
                assert info["collided"][k, i] == p_info[a]["collided"]
                assert info["covered"][k, i] == p_info[a]["covered"]
                assert p_trunc[a] == bool(dones[k])
    assert dones.all()  # every world ends at the same step: its episode length
    ep = info["episode"]
    for k, env in enumerate(envs):
        summary = env._summary()
        for key, value in summary.items():
            np.testing.assert_allclose(ep[key][k], value, atol=TOL, err_msg=key)


def test_float32_twin_matches_one_step_from_reference_states():
    envs = [parallel_env("vacl", num_agents=4) for _ in range(4)]
    for s, env in enumerate(envs):
        env.reset(seed=s)
    twin = BatchedSparseNav(4, envs[0].params)
    rng = np.random.default_rng(3)
    for _ in range(20):
        twin.set_state({k: np.concatenate([get_world_state(e)[k] for e in envs]) for k in get_world_state(envs[0])})
        actions = rng.uniform(-1, 1, (4, 4, 2)).astype(np.float32)
        obs, rew, _, _ = twin.step(actions)
        for k, env in enumerate(envs):
            p_obs, p_rew, _, _, _ = env.step({f"agent_{i}": actions[k, i] for i in range(4)})
            np.testing.assert_allclose(obs[k, 0], p_obs["agent_0"], atol=TOL)
            assert rew[k, 0] == pytest.approx(p_rew["agent_0"], abs=TOL)


# ----- the grids ------------------------------------------------------------------------------------------------
def _act(env, a0, a1):
    return env.step({"agent_0": a0, "agent_1": a1})


def test_push_box_moves_only_when_two_agents_push_the_same_way_from_the_same_side():
    env = push_box_env()
    obs, _ = env.reset(seed=0)
    assert env.pos.tolist() == [[11, 11], [9, 9]] and env.box.tolist() == [7, 7]
    np.testing.assert_allclose(obs["agent_0"], np.array([11, 11, 9, 9, 7, 7]) / 14, atol=1e-7)
    env.pos[:] = [[9, 6], [9, 8]]  # both right of the box (x = 7 + 1 + 1), within its rows 6..8
    _act(env, LEFT, STAY)  # one pusher: nothing moves, the agent is blocked by the box
    assert env.box.tolist() == [7, 7] and env.pos[0].tolist() == [9, 6]
    _act(env, LEFT, LEFT)
    assert env.box.tolist() == [6, 7] and env.pos.tolist() == [[8, 6], [8, 8]]  # agents follow into the freed cells
    env.pos[:] = [[8, 7], [6, 9]]  # one right of it, one below it: different sides
    _act(env, LEFT, UP)
    assert env.box.tolist() == [6, 7]
    env.pos[:] = [[5, 9], [7, 9]]  # both below (y = 7 + 2) pushing up
    _act(env, UP, UP)
    assert env.box.tolist() == [6, 6]
    env.pos[:] = [[10, 10], [10, 11]]  # not adjacent: pushing does nothing
    _act(env, LEFT, LEFT)
    assert env.box.tolist() == [6, 6]


def test_push_box_succeeds_and_terminates_when_the_box_touches_the_border():
    env = push_box_env()
    env.reset(seed=0)
    env.box[:] = [2, 7]
    env.pos[:] = [[4, 6], [4, 8]]
    _, rew, term, trunc, info = _act(env, LEFT, LEFT)
    assert env.box.tolist() == [1, 7]
    assert rew == {"agent_0": 1.0, "agent_1": 1.0} and all(term.values()) and not any(trunc.values())
    assert info["agent_0"]["success"] and not env.agents


def test_grids_truncate_after_300_steps_without_reward():
    for env in (push_box_env(), pass_env()):
        env.reset(seed=0)
        for t in range(300):
            _, rew, term, trunc, info = _act(env, STAY, STAY)
            assert rew["agent_0"] == 0.0 and not term["agent_0"] and trunc["agent_0"] == (t == 299)
        assert not info["agent_0"]["success"] and not env.agents


def test_pass_door_opens_only_while_an_agent_is_near_a_switch():
    env = pass_env()
    env.reset(seed=0)
    assert env.pos.tolist() == [[4, 4], [3, 3]] and env.switches.tolist() == [[3, 24], [24, 3]]
    env.pos[:] = [[14, 15], [10, 10]]
    _act(env, RIGHT, STAY)  # closed: the wall at x = 15 blocks
    assert env.pos[0].tolist() == [14, 15] and not env.door_open
    env.pos[1] = [3, 20]  # 4 from the switch (3, 24): within 4.5
    _act(env, STAY, STAY)
    assert env.door_open
    _act(env, RIGHT, STAY)
    assert env.pos[0].tolist() == [15, 15]
    env.pos[0] = [14, 11]  # outside the door's rows 12..18
    _act(env, RIGHT, STAY)
    assert env.pos[0].tolist() == [14, 11]
    env.pos[1] = [3, 19]  # 5 from the switch: the door closes
    _act(env, STAY, STAY)
    assert not env.door_open
    obs = env._observe()
    assert obs["agent_0"][-1] == 0.0 and obs["agent_1"][0] == pytest.approx(3 / 29)


def test_pass_succeeds_when_both_agents_stand_at_x_16_or_more():
    env = pass_env()
    env.reset(seed=0)
    env.door_open = True
    env.pos[:] = [[16, 15], [15, 15]]
    _, rew, term, _, _ = _act(env, STAY, STAY)  # agent 1 in the door (x = 15): not yet
    assert rew["agent_0"] == 0.0 and not term["agent_0"]
    env.door_open = True
    _, rew, term, _, info = _act(env, STAY, RIGHT)
    assert env.pos[1].tolist() == [16, 15]
    assert rew["agent_1"] == 1.0 and all(term.values()) and info["agent_1"]["success"]


@pytest.mark.parametrize("factory", ["cmcl.envs.cmae_grids:push_box_env", "cmcl.envs.cmae_grids:pass_env",
                                     "cmcl.envs.sparse_nav_v0:parallel_env"])
def test_the_factory_path_accepts_each_task(factory):
    specs = describe(load_factory(factory)())
    assert [s.team for s in specs] == ["agent"] * len(specs)
    assert all(s.discrete for s in specs) == ("cmae" in factory)
    if "cmae" in factory:
        assert specs[0].act_size == 5 and specs[0].discrete_start == 0


def test_grid_moves_follow_the_action_names():
    env = PushBoxEnv()
    env.reset()
    for act, want in ((UP, [11, 10]), (DOWN, [11, 11]), (LEFT, [10, 11]), (RIGHT, [11, 11]), (STAY, [11, 11])):
        _act(env, act, STAY)
        assert env.pos[0].tolist() == want
    env = PassEnv()
    env.reset()
    env.pos[0] = [0, 0]
    _act(env, UP, STAY)
    assert env.pos[0].tolist() == [0, 0]  # the border


# ----- presets and the grid -------------------------------------------------------------------------------------
@pytest.mark.parametrize("task", PRESETS)
def test_each_preset_is_uniform_maddpg_at_its_budget(task):
    data = load_data(ROOT / "configs" / f"{task}_maddpg.toml")
    assert data["teams"]["agent"]["algorithm"] == "maddpg"
    assert data["run"]["max_seconds"] == (7200 if task.endswith("n8") else 1800)
    assert data["env"]["success_key"] == "success"


def test_sparse_calibration_grid_has_both_algorithms_on_every_task_per_seed():
    from experiments.grids import SPARSE_TASKS, grid

    runs = grid(["sparse_calibration"], [0, 1, 2])
    assert len(runs) == 3 * 2 * len(SPARSE_TASKS) and set(SPARSE_TASKS) == set(PRESETS)
    assert [r.seed for r in runs] == sorted(r.seed for r in runs)
    for r in runs:
        assert r.config == f"{r.env}_maddpg.toml" and f"teams.agent.algorithm={r.algorithm}" in r.sets
        assert r.max_seconds == (7200 if r.env.endswith("n8") else 1800)


SPARSE_PRESETS = sorted(p.name for task in PRESETS for p in (ROOT / "configs").glob(f"{task}_*.toml"))


@pytest.mark.slow
@pytest.mark.parametrize("preset", SPARSE_PRESETS)
def test_each_preset_trains_a_few_hundred_episodes_end_to_end(preset, tmp_path):
    """Each sparse task's preset (uniform MADDPG, its curricula, curiosity as a reward), inline, 300 episodes (no
    wall-clock cap, no held-out evaluation): the run finishes and its episodes report success."""
    run_dir = tmp_path / preset.removesuffix(".toml")
    done = subprocess.run([sys.executable, "-m", "cmcl", "train", "--runner", "inline", "--config",
                           str(ROOT / "configs" / preset), "--set", "run.episodes=300",
                           "--set", "run.max_seconds=0", "--set", f"run.dir={run_dir}", "--quiet", "--no-eval"],
                          cwd=ROOT, capture_output=True, text=True, timeout=1800)
    assert done.returncode == 0, done.stderr[-2000:]
    from cmcl.run.rundir import RunDirectory

    rows = list(RunDirectory.open(run_dir).rows("episode"))
    assert len(rows) >= 300  # whole batches of env.num_envs worlds: 304
    assert all("success" in r for r in rows[-10:])

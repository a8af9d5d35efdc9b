"""Numbers that were silently wrong on your own environment, each on a real PettingZoo env:
success and coverage when agents leave early, observations that do not fit their declared space, λ's schedule on
episodes shorter than env.episode_length, and an AEC env given as the factory. tests/probe_env.py is the probe."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cmcl.config import load_config
from cmcl.envs.factory import EnvFactoryError, load_factory
from cmcl.envs.parallel_vector import CHECK_EVERY, ObservationError, VectorParallelEnv
from tests.in_process import train_tiny
from tests.test_own_env import TINY

ROOT = Path(__file__).resolve().parents[1]
PROBE = "tests.probe_env:parallel_env"


def probe(num_envs=1, episode_length=50, **kwargs):
    return VectorParallelEnv(load_factory(PROBE, kwargs), num_envs, episode_length, seed=0, auto_reset=True,
                             success_key="hit", coverage_key="hit", factory="probe")


def play(env, steps):
    """`steps` zero-action steps; the info["episode"] parts of the steps in which worlds ended."""
    parts = []
    for _ in range(steps):
        _, _, ended, info = env.step(np.zeros((env.num_envs, env.num_agents, env.act_dim), np.float32))
        if ended.any():
            parts.append(info["episode"])
    return parts


# ----- item 6: agents that left count with their final state ----------------------------------------------------
def test_success_and_coverage_count_agents_that_left_early_with_their_final_state():
    # 10 agents leave one per step; agents 0-6 succeed, 7-9 do not: true success 0.7. Before the fix only agent_9,
    # present at the last step, was counted (0.0).
    env = probe(2, agents=10, leave_at=range(1, 11), succeed=range(7), max_cycles=20)
    (ep,) = play(env, 10)
    np.testing.assert_allclose(ep["success"], [0.7, 0.7])
    np.testing.assert_allclose(ep["coverage"], [0.7, 0.7])
    np.testing.assert_array_equal(ep["length"], [10, 10])
    (again,) = play(env, 10)  # a new episode forgets the last one's values
    np.testing.assert_allclose(again["success"], [0.7, 0.7])


def test_the_last_agent_to_leave_does_not_speak_for_those_that_left_before():
    env = probe(1, agents=3, leave_at=(1, 2, 3), succeed=(2,))  # only the last one succeeds: 1/3, not 1
    (ep,) = play(env, 3)
    np.testing.assert_allclose(ep["success"], [1 / 3])


# ----- item 7: observations checked against their declared space -------------------------------------------------
@pytest.mark.parametrize("fault, says", [
    ("short", r"has shape \(1,\) \(1 values\) but its space .* has shape \(2,\)"),
    ("long", r"has shape \(3,\) \(3 values\)"),
    ("wide", r"entry 0 = 60 lies outside its space's bounds \[-1, 1\]"),
    ("nan", r"entry 1 is nan \(observations must be finite\)"),
    ("text", r"has dtype <U1, which does not cast to its space's float32"),
])
@pytest.mark.parametrize("fault_at, where", [(0, "reset"), (3, "step 3 of an episode")])
def test_an_observation_that_does_not_fit_its_space_is_refused_naming_agent_step_and_field(fault, says, fault_at,
                                                                                           where):
    with pytest.raises(ObservationError, match=rf"^probe: the observation of agent 'agent_0' at {where} \(world 0\) "
                                               rf"{says}") as err:
        env = probe(fault=fault, fault_at=fault_at)
        play(env, 3)
    assert "\n" not in str(err.value)


def test_a_short_observation_is_never_broadcast_even_on_an_unchecked_step():
    # after the first episode only one step in CHECK_EVERY gets the full check; the size is checked at every step
    env = probe(episode_length=CHECK_EVERY + 10, max_cycles=CHECK_EVERY + 10, fault="short", fault_at=3)
    play(env, 2)  # still the first episode, unaffected steps
    env._first_episode[:] = False  # as after a first episode: step 3 is not a sampled one
    with pytest.raises(ObservationError, match="step 3 of an episode"):
        play(env, 1)
    wide = probe(episode_length=CHECK_EVERY + 10, max_cycles=CHECK_EVERY + 10, fault="wide", fault_at=3)
    wide._first_episode[:] = False
    play(wide, 3)  # out-of-bounds values on an unsampled step pass: the full check is sampled, not in the hot path


def test_mpe2_observations_pass_the_full_check_at_every_step():
    env = VectorParallelEnv(load_factory("mpe2.simple_speaker_listener_v4:parallel_env",
                                         {"continuous_actions": True, "max_cycles": 25}), 2, 25, seed=0)
    env._first_episode[:] = True
    play(env, 25)  # the first episode of each world is checked in full


# ----- item 8: λ follows the steps taken ---------------------------------------------------------------------------
def probe_config(max_cycles):
    return load_config(None, [f"env.factory={PROBE}", f"env.factory_kwargs={{max_cycles={max_cycles}}}",
                              "env.episode_length=10", *TINY, "run.episodes=40", "run.smoothing_window=4"])


def lambdas(max_cycles):
    """λ of the replay server after each rollout chunk (env.num_envs whole episodes) of the run's 40 episodes, the
    roles driven by hand (no updates: λ follows the episodes stored)."""
    from services.roles.replay_server import ReplayServer
    from services.roles.rollout import RolloutWorker

    cfg = probe_config(max_cycles)
    replay, worker = ReplayServer(cfg), RolloutWorker(cfg, 0, 0)
    lams = []
    while replay.counters["episodes"] < cfg.run.episodes:
        assert replay.insert(worker.rollout(None)[0]).error is None
        lams.append(replay.schedule.lam)
    return lams


def test_lambda_reaches_its_maximum_on_schedule_when_episodes_are_shorter_than_episode_length(tmp_path):
    short, full = lambdas(5), lambdas(10)  # every episode ends after 5 of the 10 budgeted steps, or after 10
    assert full[-1] == 1.0 and short[-1] == 1.0, "before: 0.568 (200 of the 400 budgeted steps taken)"
    assert short == full, "λ per episode does not depend on how long the episodes were"
    assert len(short) == 40 // 4 and 0.1 < short[len(short) // 4] < 1.0
    summary, roles = train_tiny(probe_config(5), tmp_path / "run")  # and a run of them ends at λ_max
    assert summary["episodes"] == 40 and summary["lambda"] == roles.replay.schedule.lam == 1.0


def test_the_replay_server_counts_whole_episodes_on_the_budget_clock():
    from services.roles.replay_server import ReplayServer
    from services.roles.rollout import RolloutWorker
    from tests.tiny import make_tiny_config

    cfg = make_tiny_config("cmcl", service=True, sections={
        "env": {"factory": PROBE, "factory_kwargs": {"max_cycles": 5}, "episode_length": 10}}).to_dict()
    replay, worker = ReplayServer(cfg), RolloutWorker(cfg, 0, 0)
    for _ in range(3):
        replay.insert(worker.rollout(None)[0])
    assert replay.counters["inserts"] == 3 * 4 * 5  # the rows played
    assert replay.schedule.env_steps == 3 * 4 * 10  # before: 60, the rows; now every episode counts 10 steps


# ----- item 11: an AEC environment -----------------------------------------------------------------------------------
def test_an_aec_environment_is_named_with_the_parallel_env_to_use():
    with pytest.raises(EnvFactoryError, match=r"returned an AEC environment \(OrderEnforcingWrapper\), which steps "
                                              r"one agent at a time; .* use 'mpe2.simple_spread_v3:parallel_env'"):
        load_factory("mpe2.simple_spread_v3:env")()


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "cmcl", "train", "--runner", "inline", "--no-eval", "--quiet",
                           *args], cwd=ROOT, capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("sets, says", [
    (["env.factory=mpe2.simple_spread_v3:env"], "returned an AEC environment"),
    ([f"env.factory={PROBE}", 'env.factory_kwargs={fault="wide", fault_at=3}'],
     "the observation of agent 'agent_0' at step 3 of an episode (world 0) entry 0 = 60 lies outside"),
])
def test_the_command_line_says_what_does_not_fit_in_one_line_and_exits_2(sets, says, tmp_path):
    args = [a for s in [*sets, "run.episodes=2", f"run.dir={tmp_path / 'run'}"] for a in ("--set", s)]
    done = run_cli(*args)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: env.factory") and says in lines[0], done.stderr


# ----- item 5: a crash inside the user's environment keeps the run ---------------------------------------------------
# the service case is extended (out of the default run's budget); the inline case stays in the default run
@pytest.mark.parametrize("runner", ["inline", pytest.param("service", marks=pytest.mark.extended)])
def test_a_crash_inside_the_environment_keeps_the_run_and_resume_goes_on(runner, tmp_path):
    """The env raises at step 2 of its third episode: the run checkpoints, writes its summary (ended env_error),
    says in one line what raised where and how to resume, exit 2; resuming without the fault trains to the end."""
    run = tmp_path / "run"
    sets = [f"env.factory={PROBE}", 'env.factory_kwargs={crash_after=2, fault_at=2}', "env.num_envs=2",
            "run.episodes=12", f"run.dir={run}", "maddpg.warmup=8", "maddpg.batch_size=4", "replay.capacity=64",
            "teams.agent.algorithm=maddpg"]
    extra = ["--num-cpus", "2", "--metrics-port", "0"] if runner == "service" else []
    done = subprocess.run([sys.executable, "-m", "cmcl", "train", "--runner", runner, "--no-eval", "--quiet",
                           *[a for s in sets for a in ("--set", s)], *extra], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 2, done.stderr
    said = [line for line in done.stderr.splitlines() if line.startswith("error:")]
    assert len(said) == 1 and "RuntimeError: probe crash (at probe_env.py" in said[0], done.stderr
    assert "step 2 of world" in said[0] and "agent_0, agent_1" in said[0] and "resume with" in said[0]
    summary = json.loads((run / "summary.json").read_text())
    assert summary["ended"] == "env_error"
    again = subprocess.run([sys.executable, "-m", "cmcl", "resume", str(run), "--no-eval", "--quiet",
                            "--set", "env.factory_kwargs={}", *extra], cwd=ROOT, capture_output=True, text=True,
                           timeout=300)
    assert again.returncode == 0, again.stderr
    assert json.loads((run / "summary.json").read_text())["ended"] == "budget"

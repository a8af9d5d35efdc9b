"""The peer comparison's one held-out evaluation (bench/peer_envs.py) and our side's command (bench/peer_ours.py)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from peer_envs import ENVS, PeerEnv, eval_seeds, heldout_evaluation, random_policy  # noqa: E402
from peer_ours import NUM_ENVS, train_command  # noqa: E402

from cmcl.config import load_config  # noqa: E402

REACH = PeerEnv("reach", "reach", 2, 25, False, "cmcl.envs.examples.reach:parallel_env", (("max_cycles", 25),))


def hand_return(env_spec: PeerEnv, action: float, seed: int) -> float:
    """(1 / N) * sum over agents and steps of the reward, of one episode with a constant action."""
    env = env_spec.make()
    env.reset(seed=seed)
    total = 0.0
    while env.agents:
        _, rew, _, _, _ = env.step({a: np.full((1,), action, np.float32) for a in env.agents})
        total += sum(rew.values())
    return total / len(env.possible_agents)


def test_heldout_return_is_the_per_agent_episode_sum_on_the_given_seeds():
    seeds = eval_seeds(train_seed=1, episodes=4)
    assert seeds == [10_100_000, 10_100_001, 10_100_002, 10_100_003]
    out = heldout_evaluation(REACH, lambda obs: {a: np.full((1,), 0.05, np.float32) for a in obs}, seeds)
    expected = [hand_return(REACH, 0.05, s) for s in seeds]
    np.testing.assert_allclose(out["returns"], np.round(expected, 4))
    assert out["return_mean"] == pytest.approx(np.mean(expected))
    assert out["episodes"] == 4 and out["seeds"] == [seeds[0], seeds[-1]]
    assert len(set(out["returns"])) > 1, "each seed is its own episode"


def test_random_policy_is_reproducible_and_worse_than_moving_to_the_goal():
    seeds = eval_seeds(0, 20)
    first = heldout_evaluation(REACH, random_policy(REACH, 0), seeds)
    again = heldout_evaluation(REACH, random_policy(REACH, 0), seeds)
    assert first["returns"] == again["returns"]

    def to_goal(obs):  # observation (position, goal): step toward the goal at the Box bound 0.2
        return {a: np.clip([o[1] - o[0]], -0.2, 0.2).astype(np.float32) for a, o in obs.items()}

    assert heldout_evaluation(REACH, to_goal, seeds)["return_mean"] > first["return_mean"] + 10.0


def test_our_training_command_sets_the_env_and_an_exact_step_budget():
    spec = ENVS["simple_spread_v3"]
    cmd = train_command(spec, "maddpg", 100_000, seed=1, run_dir=Path("runs/x"))
    sets = [cmd[i + 1] for i, a in enumerate(cmd) if a == "--set"]
    config = load_config(None, sets)
    assert config.env.factory == "mpe2.simple_spread_v3:parallel_env"
    assert config.env.factory_kwargs == {"N": 3, "max_cycles": 25, "continuous_actions": True}
    assert config.env.num_envs == NUM_ENVS and config.env.episode_length == 25
    assert config.run.episodes * config.env.episode_length == 100_000 and config.run.seed == 1
    with pytest.raises(SystemExit, match="multiple"):
        train_command(spec, "maddpg", 100_000 + 25, seed=0, run_dir=Path("runs/x"))

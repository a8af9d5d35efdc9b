"""Why mpe2 simple_tag_v3 is or is not learned: one inline MADDPG run at the own_envs grid's settings
(experiments/own_envs.py, OWN_ENVS["tag"]) plus any `--set` overrides, then each team's return split into its parts.

mpe2's simple_tag pays every adversary +10 per step for each (adversary, good agent) pair in contact, so the
adversary team (3 agents) earns 30 per contact-step; the good agent pays -10 per contact and a boundary penalty per
axis per step: 0 below |x| = 0.9, 10 (|x| - 0.9) up to 1, then min(exp(2 |x| - 2), 10) (`Scenario.agent_reward`).

The run trains with the inline runner (the service's roles in this process, `services.launch.train_in_process`, in a
temporary run directory). After it, for every `--log-every` episodes of its episode rows: the team returns of
those episodes (with exploration noise) and the weight version they acted with; then the learner's last critic
loss and actor loss (-Q, so a growing magnitude means growing Q estimates) per agent. After
training, on the same 200 held-out worlds (seeded as the grid's evaluation), four pairings without noise: trained
against trained, trained adversaries against a uniformly random good agent, the trained good agent against
random adversaries, and all random. For each: the team returns, contact-steps per episode, the good agent's
boundary penalty, its steps beyond |x| or |y| = 0.9 and 1.0, its mean distance to the nearest adversary and its
largest |coordinate| (means over episodes). One JSON line per row on stdout.

    python lab/studies/own_tag_diagnosis.py --seed 0 --episodes 3000 --set maddpg.gamma=0.95 ...
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from cmcl.config import Config, load_config  # noqa: E402
from cmcl.learners.maddpg import MADDPG  # noqa: E402
from cmcl.run.evaluate import EVAL_SEED_OFFSET  # noqa: E402
from cmcl.run.rundir import RunDirectory  # noqa: E402
from cmcl.system import make_batched_env  # noqa: E402
from experiments.own_envs import OWN_ENVS  # noqa: E402

HELD_OUT = 200  # episodes, as the grid's evaluation (experiments.measures)
PAIRINGS = {"trained_vs_trained": ("trained", ()), "adversaries_vs_random_agent": ("trained", ("agent",)),
            "agent_vs_random_adversaries": ("trained", ("adversary",)), "random": ("random", ())}


def boundary_penalty(coordinate: np.ndarray) -> np.ndarray:
    """mpe2 simple_tag's penalty of one |coordinate| (float64[...] -> float64[...]), as Scenario.agent_reward."""
    x = np.abs(coordinate)
    return np.where(x < 0.9, 0.0, np.where(x < 1.0, (x - 0.9) * 10, np.minimum(np.exp(2 * x - 2), 10)))


def return_parts(config: Config, policy: MADDPG | None, random_teams: tuple[str, ...], seed: int) -> dict[str, float]:
    """One pairing on HELD_OUT held-out worlds (policy None: all random), its returns split into their parts."""
    rng = np.random.default_rng(seed + EVAL_SEED_OFFSET)
    env = make_batched_env(config, num_envs=HELD_OUT, seed=rng, auto_reset=False)
    random_agents = [a for team in random_teams for a in env.teams[team]]
    obs, returns = env.reset(), np.zeros((HELD_OUT, env.num_agents))
    per_step = {k: np.zeros(HELD_OUT) for k in ("contact_steps", "boundary_penalty", "steps_beyond_0.9",
                                                "steps_beyond_1.0", "distance_to_nearest_adversary")}
    largest = np.zeros(HELD_OUT)
    for _ in range(env.episode_length):
        uniform = rng.uniform(-1.0, 1.0, size=(HELD_OUT, env.num_agents, env.act_dim)).astype(np.float32)
        actions = uniform if policy is None else policy.act(obs, 0.0, rng=rng)
        actions[:, random_agents] = uniform[:, random_agents]
        obs, rewards, _, _ = env.step(actions)
        returns += rewards
        for w, copy in enumerate(env.envs):
            agents = copy.unwrapped.world.agents
            prey = next(a for a in agents if not a.adversary)
            chasers = [a for a in agents if a.adversary]
            distance = np.array([np.linalg.norm(prey.state.p_pos - a.state.p_pos) for a in chasers])
            position = np.abs(prey.state.p_pos)
            per_step["contact_steps"][w] += (distance < np.array([prey.size + a.size for a in chasers])).sum()
            per_step["boundary_penalty"][w] += boundary_penalty(position).sum()
            per_step["steps_beyond_0.9"][w] += (position > 0.9).any()
            per_step["steps_beyond_1.0"][w] += (position > 1.0).any()
            per_step["distance_to_nearest_adversary"][w] += distance.min() / env.episode_length
            largest[w] = max(largest[w], position.max())
    out = {f"return_{team}": float(returns[:, idx].sum(1).mean()) for team, idx in env.teams.items()}
    return {**out, **{k: float(v.mean()) for k, v in per_step.items()}, "largest_coordinate": float(largest.mean())}


def train(config: Config, log_every: int) -> MADDPG:
    """The inline run, then a training row per `log_every` episodes of its episode rows and the learner's last
    losses; returns the trained MADDPG."""
    from services.launch import train_in_process

    with tempfile.TemporaryDirectory() as tmp:
        data = config.to_dict()
        data["run"] = {**data["run"], "dir": f"{tmp}/run"}
        config = _config(data)
        run_dir = RunDirectory.create(config.run.dir, config)
        summary, roles = train_in_process(config, run_dir)
        rows = list(run_dir.rows("episode"))
    teams = list(roles.learner.layout.teams)
    for start in range(0, len(rows), log_every):
        part = rows[start:start + log_every]
        row: dict[str, Any] = {"episodes": part[-1]["episodes"], "weight_version": part[-1].get("weight_version")}
        row.update({f"return_{t}": round(float(np.mean([r["reward"][t] for r in part])), 2) for t in teams})
        print(json.dumps(row), flush=True)
    losses = roles.learner.report().learner.losses
    print(json.dumps({"episodes": summary["episodes"], "updates": summary["updates"],
                      **{f"{kind}_loss": [round(float(agent[kind]), 2) for agent in losses.values()]
                         for kind in ("critic", "actor") if losses}}), flush=True)
    return roles.learner.maddpg


def _config(data: dict[str, Any]) -> Config:
    from cmcl.config import config_from_dict

    return config_from_dict(data)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--episodes", type=int, default=OWN_ENVS["tag"].budget)
    p.add_argument("--log-every", type=int, default=250)
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="overrides after OWN_ENVS['tag']'s settings (repeatable)")
    args = p.parse_args(argv)
    env = OWN_ENVS["tag"]
    config = load_config(None, [f"env.factory={env.factory}", *env.sets, *args.sets, f"run.episodes={args.episodes}",
                                f"run.seed={args.seed}"])
    trained = train(config, args.log_every)
    for name, (who, random_teams) in PAIRINGS.items():
        policy = trained if who == "trained" else None
        print(json.dumps({"pairing": name, **return_parts(config, policy, random_teams, args.seed)}), flush=True)


if __name__ == "__main__":
    main()

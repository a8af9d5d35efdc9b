"""The own-environment grid: environments no one here wrote, trained through `env.factory` on
both runners, each against the random policy on the same held-out episodes.

OWN_ENVS names each environment with the settings it trains with (the same for both runners and every seed); its
runs are built by experiments.grids.own_env_runs, measured by `own_env_measures` and tabled by the report
(lab/report/own_env_table.py: the `ownenvs` block of lab/RESULTS.md).

A team's return is the sum over the team's agents of their episode returns (cmcl.run.evaluate.evaluate_policy), the
mean over HELD_OUT held-out episodes. With more than one team each team also plays against uniformly random
other teams ("vs random others"); the table shows it for competing teams only (`OwnEnv.competing`): both teams of
simple_tag learn against each other, so the joint return alone does not say that either learned, and a team that
learned beats the all-random return with random opponents. Cooperating teams (speaker and listener share one
reward) are judged by the joint return: a trained speaker with a random listener earns what random does.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from cmcl.run.evaluate import evaluate_policy

if TYPE_CHECKING:
    from cmcl.config import Config
    from cmcl.learners.maddpg import MADDPG

MPE_KWARGS = "env.factory_kwargs={continuous_actions=true, max_cycles=25}"
MPE_LEARNER = ("replay.capacity=50000", "maddpg.update_every=4")  # calibrated on simple_spread, seed 0 (inline)
# simple_tag: Lowe et al. (2017)'s MADDPG settings (openai/maddpg experiments/train.py: Adam lr 0.01, gamma 0.95,
# batch 1024, a warm-up of batch x episode length transitions), an update every 25 world steps instead of their 100
# and exploration noise 0.5 instead of 0.1; calibrated on simple_tag, seed 0 (inline), lab/RESULTS.md. At the spread
# settings (gamma 0.99, lr 0.001, an update every 4) both teams' critics diverged and neither team beat random.
TAG_LEARNER = ("maddpg.actor_lr=0.01", "maddpg.critic_lr=0.01", "maddpg.gamma=0.95", "maddpg.batch_size=1024",
               "maddpg.warmup=25600", "maddpg.update_every=25", "maddpg.exploration_std=0.5",
               "replay.capacity=200000")


@dataclass(frozen=True)
class OwnEnv:
    """One environment of the grid: its factory, its `--set` overrides (factory kwargs, time limit, teams and any
    learner settings), its episode budget, and whether its teams compete (then each is also shown against random
    opponents)."""

    factory: str
    sets: tuple[str, ...]
    budget: int
    label: str
    competing: bool = False


OWN_ENVS = {
    "spread": OwnEnv("mpe2.simple_spread_v3:parallel_env",
                     (MPE_KWARGS, "env.episode_length=25", "teams.agent.algorithm=maddpg", *MPE_LEARNER), 3_000,
                     "mpe2 simple_spread_v3"),
    "speaker_listener": OwnEnv("mpe2.simple_speaker_listener_v4:parallel_env",
                               (MPE_KWARGS, "env.episode_length=25", "teams.speaker.algorithm=maddpg",
                                "teams.listener.algorithm=maddpg", *MPE_LEARNER), 3_000,
                               "mpe2 simple_speaker_listener_v4"),
    "tag": OwnEnv("mpe2.simple_tag_v3:parallel_env",
                  (MPE_KWARGS, "env.episode_length=25", "teams.adversary.algorithm=maddpg",
                   "teams.agent.algorithm=maddpg", *TAG_LEARNER), 6_000, "mpe2 simple_tag_v3",
                  competing=True),
    "halfcheetah": OwnEnv("gymnasium_robotics:mamujoco_v1.parallel_env",
                          ('env.factory_kwargs={scenario="HalfCheetah", agent_conf="2x3", max_episode_steps=100}',
                           "env.episode_length=100", "teams.agent.algorithm=maddpg", "replay.capacity=60000",
                           "maddpg.update_every=4"), 600,
                          "MaMuJoCo HalfCheetah 2x3"),
}
OWN_ENV_LOG_EVERY = 100  # episodes between progress rows


def own_env_measures(config: Config, policy: MADDPG, series: dict[str, np.ndarray], held_out: dict[str, Any],
                     episodes: int, seed: int) -> dict[str, Any]:
    """The own-env measures of one run: held-out return per team (`held_out` from evaluate_policy), the random
    policy's on the same `episodes` held-out worlds (same `seed`), each team against random others when there are
    several, held-out success / coverage when the env provides them, the share of saturated actions of a continuous
    policy, and the last 100 training episodes' mean return per team. series: the run's per-episode columns
    (cmcl.run.plots.episode_series)."""
    random = evaluate_policy(config, None, episodes=episodes, seed=seed)
    teams = list(held_out["reward"])
    out: dict[str, Any] = {"held_out_return": held_out["reward"], "random_return": random["reward"],
                           "final_ma_return": {t: float(series[f"reward_{t}"][-100:].mean()) for t in teams}}
    if len(teams) > 1:
        out["vs_random_others_return"] = {
            t: evaluate_policy(config, policy, episodes, seed, random_teams=tuple(o for o in teams if o != t))
            ["reward"][t] for t in teams}
    for key in ("success", "coverage"):
        if key in held_out:
            out[f"held_out_{key}"], out[f"random_{key}"] = held_out[key], random[key]
    if "saturated_actions" in held_out:
        out["held_out_saturated_actions"] = held_out["saturated_actions"]
    if "success" in series and series["success"].size:  # the sparse screen's tie-break (docs/SPARSE_TASKS.md)
        out["final_tenth_success"] = float(series["success"][-max(1, series["success"].size // 10):].mean())
    if "task_stage" in series:
        out["task_stages"] = stage_spans(series["task_stage"])
    return out


def stage_spans(played: np.ndarray) -> list[dict[str, int]]:
    """The stages a task curriculum reached, in order, from the stage each training episode was played at
    (`played`: float64[E], episode order; earlier stages recur under the curriculum's mix): per stage k reached,
    `first_episode` (the index of its first episode) and `episodes_at_stage` (the episodes played at k from then
    until the next stage's first, the count `task_curriculum.advance = "fixed"` advances on); the last stage's span
    runs to the end of training."""
    stages = played.astype(np.int64)
    spans, top = [], int(stages.max()) if stages.size else -1
    firsts = [int(np.argmax(stages == k)) for k in range(top + 1) if np.any(stages == k)]
    for i, first in enumerate(firsts):
        end = firsts[i + 1] if i + 1 < len(firsts) else stages.size
        k = int(stages[first])
        spans.append({"stage": k, "first_episode": first, "episodes_at_stage": int(np.sum(stages[first:end] == k))})
    return spans

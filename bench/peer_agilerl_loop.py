"""AgileRL's MADDPG with its documented MPE settings, trained by AgileRL's own off-policy loop (no HPO).

Algorithm: ``agilerl.algorithms.MADDPG`` with the values of AgileRL's MPE MADDPG training config
``configs/training/multi_agent/maddpg.yaml`` (algorithm, network, replay_buffer, environment.num_envs sections):

    batch_size 64, lr_actor 1e-4, lr_critic 1e-3, learn_step 16, gamma 0.95, tau 1e-3,
    O_U_noise True, expl_noise 0.1, mean_noise 0.0, theta 0.15, dt 0.01,
    replay buffer max_size 100_000, learning_delay 0, num_envs 16,
    net_config: latent_dim 64, encoder_config.hidden_size [64], head_config.hidden_size [64, 64], ReLU.

The same values on every environment (they are AgileRL's MPE defaults; none is tuned here).

The loop is AgileRL's ``agilerl.training.train_multi_agent_off_policy`` loop for one agent, verbatim in
substance: ``get_action`` (OU noise) -> ``vec_env.step`` -> ``MultiAgentTransition(obs, raw_action, reward,
next_obs, done=termination)`` -> ``ReplayBuffer.add`` -> learn schedule (learn_step >= num_envs: one learn
every learn_step // num_envs vector steps; otherwise num_envs // learn_step learns per vector step; here
16 // 16 = 1 learn of batch 64 per vector step of 16 world steps) -> ``reset_action_noise`` for finished envs.
What is left out on purpose: the evolutionary HPO (population of 1, no tournament/mutation), and with it the
per-``evo_steps`` ``vec_env.reset()`` (which would cut an in-flight episode every 10,000 steps) and the
per-evo ``agent.test`` rollouts. So this measures AgileRL's MADDPG with fixed hyperparameters.

AgileRL behaviours that the numbers inherit (not changed here):
* agent ids "agent_0".."agent_{N-1}" share the prefix "agent", so AgileRL treats them as one homogeneous group:
  ONE shared actor and ONE shared centralised critic (parameter sharing), each ``learn`` updating it once per
  agent with that agent's own reward;
* the async vec env auto-resets inside the worker and returns the NEW episode's first observation as
  ``next_obs`` of the final transition (stored with done = termination = False, so it is bootstrapped from),
  and it drops the final step's ``info``. On our sparse env each env copy is wrapped in
  ``peer_envs.EpisodeSummaryCarrier``, which copies the finished episode's coverage/success into the info of
  the auto-reset that follows (no observation, reward or action changes); simple_spread_v3 runs unwrapped.

Counting: world steps (one step of all agents in one env copy); one vector step is ``num_envs`` world steps.
Training seconds are time.perf_counter around the training loop only (not set-up, not evaluation); the CPU
seconds of the main process and of the vec-env worker processes over the same span are recorded too.
"""

from __future__ import annotations

import functools
import os
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from peer_envs import ENVS, EpisodeSummaryCarrier, PeerEnv

# AgileRL configs/training/multi_agent/maddpg.yaml (MPE, simple_speaker_listener_v4), algorithm section.
HP: dict[str, Any] = {
    "batch_size": 64,
    "lr_actor": 0.0001,
    "lr_critic": 0.001,
    "learn_step": 16,
    "gamma": 0.95,
    "tau": 0.001,
    "O_U_noise": True,
    "expl_noise": 0.1,
    "mean_noise": 0.0,
    "theta": 0.15,
    "dt": 0.01,
}
MEMORY_SIZE = 100_000  # replay_buffer.max_size
LEARNING_DELAY = 0  # training.learning_delay
DEFAULT_NUM_ENVS = 16  # environment.num_envs
# network section (min/max bounds only matter for mutations, which are off here)
NET_CONFIG: dict[str, Any] = {
    "latent_dim": 64,
    "min_latent_dim": 8,
    "max_latent_dim": 1024,
    "encoder_config": {"hidden_size": [64], "min_mlp_nodes": 64, "max_mlp_nodes": 500},
    "head_config": {
        "hidden_size": [64, 64],
        "activation": "ReLU",
        "min_hidden_layers": 1,
        "max_hidden_layers": 2,
        "min_mlp_nodes": 64,
        "max_mlp_nodes": 500,
    },
}


def training_env(name: str):
    """One training copy of ENVS[name] (a module-level function, so the vec env can ship it to its workers)."""
    spec = ENVS[name]
    env = spec.make()
    return EpisodeSummaryCarrier(env) if spec.has_coverage else env


@dataclass
class TrainingRecord:
    """What one training run leaves: per finished episode its team return (sum over agents and steps), its end
    time (seconds into the loop) and, on our sparse env, final-step coverage and success; plus the counters."""

    world_steps: int = 0
    learn_calls: int = 0
    seconds: float = 0.0
    cpu_main: float = 0.0
    cpu_workers: float = 0.0
    loadavg: list[float] = field(default_factory=list)
    team_return: list[float] = field(default_factory=list)
    end_time: list[float] = field(default_factory=list)
    coverage: list[float] = field(default_factory=list)
    success: list[float] = field(default_factory=list)


def cpu_seconds() -> tuple[float, float]:
    """(this process's CPU seconds, its live child processes' CPU seconds: the vec-env workers)."""
    import psutil

    me = psutil.Process()
    kids = 0.0
    for c in me.children(recursive=True):
        try:
            t = c.cpu_times()
            kids += t.user + t.system
        except psutil.Error:
            pass
    t = me.cpu_times()
    return t.user + t.system, kids


def build_agent(env_spec: PeerEnv, num_envs: int, seed: int):
    """(vec env, its first obs and info, the MADDPG agent, the replay buffer, agent ids): AgileRL's set-up."""
    from agilerl.algorithms import MADDPG
    from agilerl.components.replay_buffer import ReplayBuffer
    from agilerl.vector.pz_async_vec_env import AsyncPettingZooVecEnv

    make = functools.partial(training_env, env_spec.name)
    env = AsyncPettingZooVecEnv([make for _ in range(num_envs)])
    obs, info = env.reset(seed=1000 * seed)  # sub-env i is seeded 1000 * seed + i, then its own RNG stream
    agent_ids = list(env.agents)
    agent = MADDPG(
        observation_spaces=[env.single_observation_space(a) for a in agent_ids],
        action_spaces=[env.single_action_space(a) for a in agent_ids],
        agent_ids=agent_ids,
        vect_noise_dim=num_envs,
        net_config=NET_CONFIG,
        device="cpu",
        **HP,
    )
    return env, obs, info, agent, ReplayBuffer(max_size=MEMORY_SIZE, device="cpu"), agent_ids


def train(env_spec: PeerEnv, env, obs, info, agent, memory, agent_ids: list[str], env_steps: int,
          log_every: int) -> TrainingRecord:
    """AgileRL's off-policy loop (module docstring) for env_steps // num_envs vector steps."""
    from agilerl.components.data import MultiAgentTransition, transition_to_tensordict

    num_envs = env.num_envs
    rec = TrainingRecord()
    scores = np.zeros(num_envs)
    agent.set_training_mode(True)
    agent.init_training_step()
    rec.loadavg.append(os.getloadavg()[0])
    cpu0 = cpu_seconds()
    t0 = time.perf_counter()
    for idx_step in range(env_steps // num_envs):
        action, raw_action = agent.get_action(obs=obs, infos=info)
        next_obs, reward, termination, truncation, info = env.step(action)
        rec.world_steps += num_envs
        r = np.column_stack([np.asarray(reward[a]).ravel() for a in agent_ids])
        scores += np.nan_to_num(r).sum(axis=1)

        transition = transition_to_tensordict(
            MultiAgentTransition(obs=obs, action=raw_action, reward=reward, next_obs=next_obs, done=termination)
        )
        transition.batch_size = torch.Size([num_envs])
        memory.add(transition)

        if agent.learn_step > num_envs:
            learn_step = agent.learn_step // num_envs
            if idx_step % learn_step == 0 and len(memory) >= agent.batch_size and memory.counter > LEARNING_DELAY:
                agent.learn(memory.sample(agent.batch_size))
                rec.learn_calls += 1
        elif len(memory) >= agent.batch_size and memory.counter > LEARNING_DELAY:
            for _ in range(num_envs // agent.learn_step):
                agent.learn(memory.sample(agent.batch_size))
                rec.learn_calls += 1

        obs = next_obs

        done = np.ones(num_envs, dtype=bool)
        for a in agent_ids:
            d = np.asarray(termination[a], dtype=float)
            t = np.asarray(truncation[a], dtype=float)
            done &= np.where(np.isnan(d), True, d.astype(bool)) | np.where(np.isnan(t), False, t.astype(bool))
        finished = np.nonzero(done)[0].tolist()
        if finished:
            _record_finished(rec, env_spec, info[agent_ids[0]], finished, scores, time.perf_counter() - t0, log_every)
            agent.reset_action_noise(finished)
    rec.seconds = time.perf_counter() - t0
    cpu1 = cpu_seconds()
    rec.cpu_main, rec.cpu_workers = cpu1[0] - cpu0[0], cpu1[1] - cpu0[1]
    rec.loadavg.append(os.getloadavg()[0])
    agent.add_scores(rec.team_return)
    agent.finalize_training_step(rec.world_steps)
    env.close()
    return rec


def _record_finished(rec: TrainingRecord, env_spec: PeerEnv, info0: dict[str, Any], finished: list[int],
                     scores: np.ndarray, now: float, log_every: int) -> None:
    """Append the finished envs' episodes to `rec` (zeroing their scores); print a progress line every log_every."""
    n = len(scores)
    if env_spec.has_coverage:
        covs = np.asarray(info0.get("prev_ep_coverage", np.full(n, np.nan)), dtype=float)
        mask = np.asarray(info0.get("_prev_ep_coverage", np.zeros(n, dtype=bool)), dtype=bool)
        succs = np.asarray(info0.get("prev_ep_success", np.full(n, np.nan)), dtype=float)
    for i in finished:
        if env_spec.has_coverage:
            if not mask[i]:
                raise RuntimeError(f"env {i} finished but its episode summary did not arrive: {info0}")
            rec.coverage.append(float(covs[i]))
            rec.success.append(float(succs[i]))
        rec.end_time.append(now)
        rec.team_return.append(float(scores[i]))
        scores[i] = 0.0
        if len(rec.team_return) % log_every == 0:
            cov = f" ma100_cov {np.mean(rec.coverage[-100:]):.3f}" if rec.coverage else ""
            print(f"ep {len(rec.team_return)} world_steps {rec.world_steps} t {now:.1f}s{cov} "
                  f"ma100_team_return {np.mean(rec.team_return[-100:]):.2f} learn_calls {rec.learn_calls}", flush=True)

"""Peer measurement: AgileRL's MADDPG (fixed documented MPE defaults, no HPO) on our sparse_spread_v0.

What it runs
------------
Env: ``cmcl.envs.sparse_spread_v0.parallel_env(num_agents=4, max_cycles=30, shared_reward=False)``, vectorised
with AgileRL's own ``agilerl.vector.pz_async_vec_env.AsyncPettingZooVecEnv`` (one subprocess per env copy, as in
AgileRL's ``demos/multi_agent/demo_multi_agent.py`` and the MADDPG API page's "Example Training Loop").

Algorithm: ``agilerl.algorithms.MADDPG`` with the values of AgileRL's MPE MADDPG training config
``configs/training/multi_agent/maddpg.yaml`` (algorithm, network, replay_buffer, environment.num_envs sections):

    batch_size 64, lr_actor 1e-4, lr_critic 1e-3, learn_step 16, gamma 0.95, tau 1e-3,
    O_U_noise True, expl_noise 0.1, mean_noise 0.0, theta 0.15, dt 0.01,
    replay buffer max_size 100_000, learning_delay 0, num_envs 16,
    net_config: latent_dim 64, encoder_config.hidden_size [64], head_config.hidden_size [64, 64], ReLU.

The inner loop is AgileRL's ``agilerl.training.train_multi_agent_off_policy`` loop for one agent, verbatim in
substance: ``get_action`` (OU noise) -> ``vec_env.step`` -> ``MultiAgentTransition(obs, raw_action, reward,
next_obs, done=termination)`` -> ``ReplayBuffer.add`` -> learn schedule (learn_step >= num_envs: one learn
every learn_step // num_envs vector steps; otherwise num_envs // learn_step learns per vector step; here
16 // 16 = 1 learn of batch 64 per vector step of 16 world steps) -> ``reset_action_noise`` for finished envs.
What is left out on purpose: the evolutionary HPO (population of 1, no tournament/mutation), and with it the
per-``evo_steps`` ``vec_env.reset()`` (which would cut an in-flight episode every 10,000 steps) and the
per-evo ``agent.test`` rollouts. So this measures AgileRL's MADDPG with fixed hyperparameters.

AgileRL behaviours that the numbers inherit (not changed here):
* agent ids "agent_0".."agent_3" share the prefix "agent", so AgileRL treats them as one homogeneous group:
  ONE shared actor and ONE shared centralised critic (parameter sharing), each ``learn`` updating it once per
  agent with that agent's own reward;
* the async vec env auto-resets inside the worker and returns the NEW episode's first observation as
  ``next_obs`` of the final transition (stored with done = termination = False, so it is bootstrapped from),
  and it drops the final step's ``info`` (our "episode" summary). To log training coverage this script wraps
  each env copy in ``EpisodeSummaryCarrier``, which copies the finished episode's final-step coverage/success
  into the info of the auto-reset that follows; it changes no observation, reward or action.

Counting: ``--env-steps`` counts world steps (one step of all 4 agents in one env copy); one vector step is
``num_envs`` world steps. 600,000 = 20,000 episodes x 30 steps. Training seconds are time.perf_counter around
the training loop only (not set-up, not evaluation); the CPU seconds of the main process and of the vec-env
worker processes over the same span are recorded too (a contention-robust cost), with the 1-min load average.
Held-out evaluation: ``--eval-episodes`` fresh episodes of a plain (unwrapped) env with seeds never used in
training, deterministic actor (``set_training_mode(False)``: no noise); final-step landmark coverage and
success are read from our env's info["episode"].

Install (a venv outside the repo; torch stays the local CPU wheel; AgileRL with --no-deps because it pins
pettingzoo<1.27 and asks for torch, jax, minari, wandb extras etc.; only what it imports at run time is added):

    python3 -m venv /work/peer-venv
    /work/peer-venv/bin/pip install torch==2.13.0
    /work/peer-venv/bin/pip install -e /work/main
    /work/peer-venv/bin/pip install --no-deps agilerl==2.58.0 "agilerl-arena>=1.28,<2" tensordict==0.13.0 \
        accelerate peft transformers wandb dill fastrand xxhash regex
    /work/peer-venv/bin/pip install lazy-loader importlib_metadata orjson pyvers huggingface_hub safetensors \
        tokenizers typer

(agilerl 2.58 imports peft -> transformers unconditionally via agilerl.distributed, and wandb/fastrand/xxhash
at import time; transformers needs tokenizers to import. None of these replaces torch.)

Usage:

    OMP_NUM_THREADS=1 nice -n 19 /work/peer-venv/bin/python bench/peer_agilerl.py \
        --env-steps 600000 --seed 0 --num-envs 16 --eval-episodes 200 --out results.json

Prints progress lines, then a one-line JSON summary (also written to --out).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import random
import sys
import time
from collections import deque
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")
os.environ.setdefault("WANDB_MODE", "disabled")

import numpy as np  # noqa: E402
import torch  # noqa: E402
from pettingzoo.utils.wrappers import BaseParallelWrapper  # noqa: E402

from cmcl.envs import sparse_spread_v0  # noqa: E402

NUM_AGENTS = 4
MAX_CYCLES = 30

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


def make_env():
    return sparse_spread_v0.parallel_env(num_agents=NUM_AGENTS, max_cycles=MAX_CYCLES, shared_reward=False)


class EpisodeSummaryCarrier(BaseParallelWrapper):
    """Copies the last finished episode's final-step coverage/success into the next reset's infos.

    AgileRL's async vec env auto-resets in the worker and returns the reset's infos in place of the final
    step's, so our info["episode"] never reaches the training loop. Nothing else is changed.
    """

    def __init__(self, env):
        super().__init__(env)
        self._last: dict[str, float] | None = None

    # explicit forwards (ParallelEnv class attributes would otherwise shadow __getattr__)
    @property
    def possible_agents(self):
        return self.env.possible_agents

    @property
    def agents(self):
        return self.env.agents

    @property
    def metadata(self):
        return self.env.metadata

    @property
    def render_mode(self):
        return self.env.render_mode

    def observation_space(self, agent):
        return self.env.observation_space(agent)

    def action_space(self, agent):
        return self.env.action_space(agent)

    def step(self, actions):
        obs, rew, terms, truncs, infos = self.env.step(actions)
        for info in infos.values():
            if "episode" in info:
                ep = info["episode"]
                self._last = {"coverage": float(ep["coverage"]), "success": float(bool(ep["success"]))}
                break
        return obs, rew, terms, truncs, infos

    def reset(self, seed=None, options=None):
        obs, infos = self.env.reset(seed=seed, options=options)
        if self._last is not None:
            for name in infos:
                infos[name] = {
                    **infos[name],
                    "prev_ep_coverage": self._last["coverage"],
                    "prev_ep_success": self._last["success"],
                }
            self._last = None
        return obs, infos


def make_wrapped_env():
    return EpisodeSummaryCarrier(make_env())


def first_ma_crossing(values: list[float], times: list[float], window: int, threshold: float):
    """1-based episode index (and its seconds) where the `window`-episode moving average first reaches threshold."""
    if len(values) < window:
        return None, None
    c = np.cumsum(np.asarray(values, dtype=np.float64))
    ma = (c[window - 1 :] - np.concatenate([[0.0], c[:-window]])) / window
    hits = np.nonzero(ma >= threshold - 1e-12)[0]
    if hits.size == 0:
        return None, None
    k = int(hits[0]) + window  # episodes completed
    return k, float(times[k - 1])


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


def evaluate(agent, n_episodes: int, seed_base: int) -> dict[str, Any]:
    """Deterministic (no noise) rollouts of the trained actor on fresh, held-out episodes of the plain env."""
    agent.set_training_mode(False)
    env = make_env()
    cov, succ = [], []
    t0 = time.perf_counter()
    for k in range(n_episodes):
        obs, info = env.reset(seed=seed_base + k)
        ep = None
        while env.agents:
            batched = {a: o[None, :] for a, o in obs.items()}
            action, _ = agent.get_action(obs=batched, infos=None)
            act = {a: np.asarray(action[a], dtype=np.float32).reshape(-1, 2)[0] for a in obs}
            obs, _, _, _, info = env.step(act)
            for i in info.values():
                if "episode" in i:
                    ep = i["episode"]
        assert ep is not None
        cov.append(float(ep["coverage"]))
        succ.append(float(bool(ep["success"])))
    env.close()
    return {
        "episodes": n_episodes,
        "coverage_mean": float(np.mean(cov)),
        "coverage_std": float(np.std(cov)),
        "success_rate": float(np.mean(succ)),
        "seconds": time.perf_counter() - t0,
        "seeds": [seed_base, seed_base + n_episodes - 1],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--env-steps", type=int, default=600_000, help="world steps (one step of all agents, one env)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--num-envs", type=int, default=DEFAULT_NUM_ENVS, help="AgileRL vector size (yaml: 16)")
    ap.add_argument("--eval-episodes", type=int, default=200)
    ap.add_argument("--out", default="results.json")
    ap.add_argument("--log-every", type=int, default=1000, help="print progress every N finished episodes")
    args = ap.parse_args()

    torch.set_num_threads(1)
    random.seed(args.seed)
    np.random.seed(args.seed)  # noqa: NPY002  (the legacy global RNG, for any library code that uses it)
    torch.manual_seed(args.seed)

    from importlib.metadata import version as _pkg_version

    from agilerl.algorithms import MADDPG
    from agilerl.components.data import MultiAgentTransition, transition_to_tensordict
    from agilerl.components.replay_buffer import ReplayBuffer
    from agilerl.vector.pz_async_vec_env import AsyncPettingZooVecEnv

    try:
        import fastrand

        fastrand.pcg32_seed(args.seed)
    except Exception:  # noqa: BLE001
        pass

    agilerl_version = _pkg_version("agilerl")
    t_setup = time.perf_counter()
    num_envs = args.num_envs
    env = AsyncPettingZooVecEnv([make_wrapped_env for _ in range(num_envs)])
    train_seed_base = 1000 * args.seed  # sub-env i is seeded train_seed_base + i, then its own RNG stream
    obs, info = env.reset(seed=train_seed_base)
    agent_ids = list(env.agents)
    observation_spaces = [env.single_observation_space(a) for a in agent_ids]
    action_spaces = [env.single_action_space(a) for a in agent_ids]

    agent = MADDPG(
        observation_spaces=observation_spaces,
        action_spaces=action_spaces,
        agent_ids=agent_ids,
        vect_noise_dim=num_envs,
        net_config=NET_CONFIG,
        device="cpu",
        **HP,
    )
    memory = ReplayBuffer(max_size=MEMORY_SIZE, device="cpu")
    n_params = {
        name: int(sum(p.numel() for p in net.parameters()))
        for name, net in (("actors", agent.actors), ("critics", agent.critics))
    }
    setup_seconds = time.perf_counter() - t_setup

    vec_steps = args.env_steps // num_envs
    world_steps = 0
    learn_calls = 0
    ep_cov: list[float] = []
    ep_succ: list[float] = []
    ep_time: list[float] = []
    ep_return: list[float] = []
    scores = np.zeros(num_envs)
    recent = deque(maxlen=100)
    ma09 = (None, None)

    agent.set_training_mode(True)
    agent.init_training_step()
    print(
        f"agilerl {agilerl_version} torch {torch.__version__} num_envs={num_envs} vec_steps={vec_steps} "
        f"world_steps={vec_steps * num_envs} shared_groups={agent.shared_agent_ids} params={n_params}",
        flush=True,
    )
    load_start = os.getloadavg()
    cpu0 = cpu_seconds()
    t0 = time.perf_counter()
    for idx_step in range(vec_steps):
        action, raw_action = agent.get_action(obs=obs, infos=info)
        next_obs, reward, termination, truncation, info = env.step(action)
        world_steps += num_envs
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
                learn_calls += 1
        elif len(memory) >= agent.batch_size and memory.counter > LEARNING_DELAY:
            for _ in range(num_envs // agent.learn_step):
                agent.learn(memory.sample(agent.batch_size))
                learn_calls += 1

        obs = next_obs

        done = np.ones(num_envs, dtype=bool)
        for a in agent_ids:
            d = np.asarray(termination[a], dtype=float)
            t = np.asarray(truncation[a], dtype=float)
            done &= np.where(np.isnan(d), True, d.astype(bool)) | np.where(np.isnan(t), False, t.astype(bool))
        finished = np.nonzero(done)[0].tolist()
        if finished:
            now = time.perf_counter() - t0
            a0 = info[agent_ids[0]]
            covs = np.asarray(a0.get("prev_ep_coverage", np.full(num_envs, np.nan)), dtype=float)
            mask = np.asarray(a0.get("_prev_ep_coverage", np.zeros(num_envs, dtype=bool)), dtype=bool)
            succs = np.asarray(a0.get("prev_ep_success", np.full(num_envs, np.nan)), dtype=float)
            for i in finished:
                if not mask[i]:
                    raise RuntimeError(f"env {i} finished but its episode summary did not arrive: {a0}")
                ep_cov.append(float(covs[i]))
                ep_succ.append(float(succs[i]))
                ep_time.append(now)
                ep_return.append(float(scores[i]))
                scores[i] = 0.0
                recent.append(float(covs[i]))
                if ma09[0] is None and len(recent) == 100 and np.mean(recent) >= 0.9 - 1e-12:
                    ma09 = (len(ep_cov), now)
                if len(ep_cov) % args.log_every == 0:
                    print(
                        f"ep {len(ep_cov)} world_steps {world_steps} t {now:.1f}s ma100_cov {np.mean(recent):.3f} "
                        f"ma100_succ {np.mean(ep_succ[-100:]):.2f} ma100_team_return {np.mean(ep_return[-100:]):.2f} "
                        f"learn_calls {learn_calls}",
                        flush=True,
                    )
            agent.reset_action_noise(finished)
    train_seconds = time.perf_counter() - t0
    cpu1 = cpu_seconds()
    load_end = os.getloadavg()
    agent.add_scores(ep_return)
    agent.finalize_training_step(world_steps)
    env.close()

    k, s = first_ma_crossing(ep_cov, ep_time, 100, 0.9)
    assert (k, s) == ma09 or ma09[0] is None and k is None, (k, s, ma09)

    eval_seed_base = 10_000_000 + 100_000 * args.seed
    ev = evaluate(agent, args.eval_episodes, eval_seed_base)

    last = min(1000, len(ep_cov))
    summary = {
        "peer": "agilerl.MADDPG",
        "agilerl_version": agilerl_version,
        "torch_version": torch.__version__,
        "python": platform.python_version(),
        "env": f"sparse_spread_v0(num_agents={NUM_AGENTS}, max_cycles={MAX_CYCLES}, shared_reward=False)",
        "vec_env": "agilerl.vector.pz_async_vec_env.AsyncPettingZooVecEnv",
        "seed": args.seed,
        "num_envs": num_envs,
        "env_steps": world_steps,
        "env_steps_requested": args.env_steps,
        "train_episodes": len(ep_cov),
        "learn_calls": learn_calls,
        "hyperparameters": {
            **HP,
            "memory_size": MEMORY_SIZE,
            "learning_delay": LEARNING_DELAY,
            "net_config": NET_CONFIG,
            "hpo": False,
            "population": 1,
        },
        "shared_networks": agent.shared_agent_ids,
        "n_params": n_params,
        "torch_threads": torch.get_num_threads(),
        "setup_seconds": setup_seconds,
        "train_seconds": train_seconds,
        "train_steps_per_second": world_steps / train_seconds,
        "train_cpu_seconds_main": cpu1[0] - cpu0[0],
        "train_cpu_seconds_workers": cpu1[1] - cpu0[1],
        "loadavg_1min_start_end": [load_start[0], load_end[0]],
        "train_coverage_last1000": float(np.mean(ep_cov[-last:])) if ep_cov else None,
        "train_success_last1000": float(np.mean(ep_succ[-last:])) if ep_succ else None,
        "train_coverage_ma100_final": float(np.mean(ep_cov[-100:])) if ep_cov else None,
        "ma100_coverage_0.9_episode": k,
        "ma100_coverage_0.9_seconds": s,
        "eval_episodes": ev["episodes"],
        "eval_coverage": ev["coverage_mean"],
        "eval_coverage_std": ev["coverage_std"],
        "eval_success": ev["success_rate"],
        "eval_seconds": ev["seconds"],
        "eval_seeds": ev["seeds"],
        "train_coverage_curve_per1000": [float(np.mean(ep_cov[i : i + 1000])) for i in range(0, len(ep_cov), 1000)],
        "argv": sys.argv[1:],
    }
    line = json.dumps(summary, separators=(",", ":"))
    with open(args.out, "w") as f:
        f.write(line + "\n")
    print(line, flush=True)


if __name__ == "__main__":
    main()

"""Peer measurement: AgileRL's MADDPG (fixed documented MPE defaults, no HPO) on a peer environment.

What it runs
------------
Env (``--env``, `bench/peer_envs.py`): ``sparse_spread`` = ours, ``sparse_spread_v0.parallel_env(num_agents=4,
max_cycles=30, shared_reward=False)``; ``simple_spread_v3`` = mpe2's ``simple_spread_v3.parallel_env(N=3,
max_cycles=25, continuous_actions=True)``. Vectorised with AgileRL's own
``agilerl.vector.pz_async_vec_env.AsyncPettingZooVecEnv`` (one subprocess per env copy, as in AgileRL's
``demos/multi_agent/demo_multi_agent.py`` and the MADDPG API page's "Example Training Loop").

Algorithm, settings and loop: `bench/peer_agilerl_loop.py` (AgileRL's MPE MADDPG yaml values, AgileRL's
off-policy loop without the evolutionary HPO; the same values on both environments).

Counting: ``--env-steps`` counts world steps (one step of all agents in one env copy); one vector step is
``num_envs`` world steps. On sparse_spread 600,000 = 20,000 episodes x 30 steps; on simple_spread_v3
200,000 = 8,000 episodes x 25 steps.
Held-out evaluation (`peer_envs.heldout_evaluation`, the same for our side, `bench/peer_ours.py`):
``--eval-episodes`` fresh episodes of a plain (unwrapped) env reset with seeds never used in training
(`peer_envs.eval_seeds`), deterministic actor (``set_training_mode(False)``: no noise); the return per agent
summed over the episode, and on our sparse env final-step landmark coverage and success; the random policy's
return on the same episodes.

Install (a venv outside the package; torch stays the local CPU wheel; AgileRL with --no-deps because it pins
pettingzoo<1.27 and asks for torch, jax, minari, wandb extras etc.; only what it imports at run time is added):
``make peer`` (Makefile), i.e.

    python3 -m venv .venv-peer
    .venv-peer/bin/pip install torch==2.13.0
    .venv-peer/bin/pip install -e .
    .venv-peer/bin/pip install --no-deps agilerl==2.58.0 "agilerl-arena>=1.28,<2" tensordict==0.13.0 \
        accelerate peft transformers wandb dill fastrand xxhash regex
    .venv-peer/bin/pip install lazy-loader importlib_metadata orjson pyvers huggingface_hub safetensors \
        tokenizers typer

(agilerl 2.58 imports peft -> transformers unconditionally via agilerl.distributed, and wandb/fastrand/xxhash
at import time; transformers needs tokenizers to import. None of these replaces torch.)

Usage:

    OMP_NUM_THREADS=1 nice -n 10 .venv-peer/bin/python bench/peer_agilerl.py --env simple_spread_v3 \
        --env-steps 200000 --seed 0 --num-envs 16 --eval-episodes 200 --out results.json

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
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")
os.environ.setdefault("WANDB_MODE", "disabled")

import numpy as np  # noqa: E402
import torch  # noqa: E402
from peer_agilerl_loop import (  # noqa: E402
    DEFAULT_NUM_ENVS,
    HP,
    LEARNING_DELAY,
    MEMORY_SIZE,
    NET_CONFIG,
    TrainingRecord,
    build_agent,
    train,
)
from peer_envs import ENVS, PeerEnv, eval_seeds, heldout_evaluation, random_policy  # noqa: E402

from cmcl.run.provenance import provenance  # noqa: E402


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


def agilerl_policy(agent):
    """The trained actor without noise as a PettingZoo policy: obs dict -> {agent: action of its Box shape}."""
    agent.set_training_mode(False)

    def act(obs):
        action, _ = agent.get_action(obs={a: o[None, :] for a, o in obs.items()}, infos=None)
        return {a: np.asarray(action[a], dtype=np.float32)[0] for a in obs}

    return act


def coverage_fields(env_spec: PeerEnv, rec: TrainingRecord, ev: dict[str, Any]) -> dict[str, Any]:
    """The coverage/success entries of the summary (our sparse env only; unchanged names from earlier results)."""
    if not env_spec.has_coverage:
        return {}
    cov, succ = rec.coverage, rec.success
    k, s = first_ma_crossing(cov, rec.end_time, 100, 0.9)
    last = min(1000, len(cov))
    return {
        "train_coverage_last1000": float(np.mean(cov[-last:])) if cov else None,
        "train_success_last1000": float(np.mean(succ[-last:])) if succ else None,
        "train_coverage_ma100_final": float(np.mean(cov[-100:])) if cov else None,
        "ma100_coverage_0.9_episode": k,
        "ma100_coverage_0.9_seconds": s,
        "eval_coverage": ev["coverage_mean"],
        "eval_coverage_std": ev["coverage_std"],
        "eval_success": ev["success_rate"],
        "train_coverage_curve_per1000": [float(np.mean(cov[i : i + 1000])) for i in range(0, len(cov), 1000)],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--env", choices=sorted(ENVS), default="sparse_spread")
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

    try:
        import fastrand

        fastrand.pcg32_seed(args.seed)
    except Exception:  # noqa: BLE001
        pass

    env_spec = ENVS[args.env]
    agilerl_version = _pkg_version("agilerl")
    t_setup = time.perf_counter()
    env, obs, info, agent, memory, agent_ids = build_agent(env_spec, args.num_envs, args.seed)
    n_params = {
        name: int(sum(p.numel() for p in net.parameters()))
        for name, net in (("actors", agent.actors), ("critics", agent.critics))
    }
    setup_seconds = time.perf_counter() - t_setup
    print(f"agilerl {agilerl_version} torch {torch.__version__} env={args.env} num_envs={args.num_envs} "
          f"world_steps={args.env_steps // args.num_envs * args.num_envs} shared_groups={agent.shared_agent_ids} "
          f"params={n_params}", flush=True)
    rec = train(env_spec, env, obs, info, agent, memory, agent_ids, args.env_steps, args.log_every)

    seeds = eval_seeds(args.seed, args.eval_episodes)
    t_eval = time.perf_counter()
    ev = heldout_evaluation(env_spec, agilerl_policy(agent), seeds)
    eval_seconds = time.perf_counter() - t_eval
    rnd = heldout_evaluation(env_spec, random_policy(env_spec, args.seed), seeds)
    n = len(agent_ids)
    summary = {
        "peer": "agilerl.MADDPG",
        "library": "agilerl",
        "algorithm": "maddpg",
        "agilerl_version": agilerl_version,
        "torch_version": torch.__version__,
        "python": platform.python_version(),
        "env": env_spec.label,
        "vec_env": "agilerl.vector.pz_async_vec_env.AsyncPettingZooVecEnv",
        "seed": args.seed,
        "num_envs": args.num_envs,
        "env_steps": rec.world_steps,
        "env_steps_requested": args.env_steps,
        "train_episodes": len(rec.team_return),
        "learn_calls": rec.learn_calls,
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
        "train_seconds": rec.seconds,
        "train_steps_per_second": rec.world_steps / rec.seconds,
        "train_cpu_seconds_main": rec.cpu_main,
        "train_cpu_seconds_workers": rec.cpu_workers,
        "train_cpu_seconds": rec.cpu_main + rec.cpu_workers,
        "loadavg_1min_start_end": rec.loadavg,
        "train_return_per_agent_last100": float(np.mean(rec.team_return[-100:])) / n if rec.team_return else None,
        "eval_episodes": ev["episodes"],
        "eval_seeds": ev["seeds"],
        "eval_seconds": eval_seconds,
        "eval_return": ev["return_mean"],
        "eval_return_std": ev["return_std"],
        "random_return": rnd["return_mean"],
        "random_return_std": rnd["return_std"],
        **coverage_fields(env_spec, rec, ev),
        "train_return_per_agent_curve_per1000": [float(np.mean(rec.team_return[i : i + 1000])) / n
                                                 for i in range(0, len(rec.team_return), 1000)],
        "eval_returns": ev["returns"],
        "argv": sys.argv[1:],
    }
    line = json.dumps({**summary, "provenance": provenance()}, separators=(",", ":"))
    with open(args.out, "w") as f:
        f.write(line + "\n")
    print(line, flush=True)


if __name__ == "__main__":
    main()

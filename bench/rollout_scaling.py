"""Rollout scaling on a slow environment: env steps/s with 1, 2 and 4 rollout workers, and on a
2-node cluster that workers on both nodes contribute.

1. Per-step cost of each environment of the own_envs grid (experiments.own_envs.OWN_ENVS): CPU microseconds per
   world step of the vectorising adapter (16 copies, uniform random actions), in this process (CPU time, so a
   loaded machine does not inflate it).
2. On the slowest: the service's rollout workers (services.roles.rollout.RolloutWorker as Ray actors, each with
   `service.rollout_cpus` as `services.runtime.placement` starts them) on an embedded Ray of this machine's cores, with
   1, 2 and 4 workers, each keeping one `rollout` call in flight for `--seconds`; env steps/s from the workers'
   cumulative counters (after one warm-up call each) and the ratio against the 1-worker run of the same process.
   Only the rollout side runs (the chunks are dropped, no learner): this measures what more workers add to
   stepping, not the learner's rate.
3. A 2-node `ray.cluster_utils.Cluster` (1 CPU each, as tests/node_loss_scenario.py makes it): 2 workers of 1 CPU
   each, so one lands on each node; the env steps of each node.

The load average is printed with the numbers: on a shared machine the absolute rates mean little, the ratios of
one process a little more.

    python bench/rollout_scaling.py [--seconds 20] [--workers 1 2 4] [--out lab/results/rollout_scaling]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from cmcl.config import Config, load_config
from cmcl.run.provenance import provenance
from cmcl.system import make_batched_env
from experiments.own_envs import OWN_ENVS

COPIES = 16  # env.num_envs of every worker (the default)


def env_config(name: str, *extra: str) -> Config:
    env = OWN_ENVS[name]
    return load_config(None, [f"env.factory={env.factory}", *env.sets, f"env.num_envs={COPIES}", *extra])


def per_step_us(name: str, steps: int = 40) -> float:
    """CPU microseconds per world step of env `name` through the adapter (COPIES copies, random actions)."""
    env = make_batched_env(env_config(name), num_envs=COPIES, seed=np.random.default_rng(0), auto_reset=True)
    rng = np.random.default_rng(1)
    env.reset()
    act = lambda: rng.uniform(-1, 1, (COPIES, env.num_agents, env.act_dim)).astype(np.float32)  # noqa: E731
    for _ in range(5):
        env.step(act())
    start = time.process_time()
    for _ in range(steps):
        env.step(act())
    return (time.process_time() - start) / (steps * COPIES) * 1e6


def rollout_rate(config: Config, workers: int, seconds: float, cpus: float) -> dict:
    """Env steps/s of `workers` rollout actors on the current Ray cluster, each keeping one call in flight; the
    steps of each node; the CPU seconds the workers' processes used in the window (psutil, by the pid the GCS
    lists: on a loaded machine the wall-clock rate follows the CPU share the workers get, the steps per CPU second
    do not)."""
    import psutil
    import ray

    from services.roles.rollout import RolloutWorker
    from tests.faults import actor_entry

    cls = ray.remote(num_cpus=cpus, max_restarts=0)(RolloutWorker)
    actors = [cls.remote(config.to_dict(), w, 1000 + w) for w in range(workers)]
    first = ray.get([a.rollout.remote(None) for a in actors])  # warm-up: the env built, one chunk each
    base = [report.rollout.env_steps for _, report in first]
    last = list(base)
    procs = [psutil.Process(int(actor_entry(a)["Pid"])) for a in actors]
    cpu_base = [sum(p.cpu_times()[:2]) for p in procs]
    pending = {a.rollout.remote(None): i for i, a in enumerate(actors)}
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        done, _ = ray.wait(list(pending), num_returns=1)
        i = pending.pop(done[0])
        last[i] = ray.get(done[0])[1].rollout.env_steps
        pending[actors[i].rollout.remote(None)] = i
    elapsed = time.perf_counter() - start
    cpu = sum(sum(p.cpu_times()[:2]) - c for p, c in zip(procs, cpu_base, strict=True))
    nodes = [actor_entry(a)["Address"]["NodeID"] for a in actors]
    for a in actors:
        ray.kill(a)
    steps = [b - a for a, b in zip(base, last, strict=True)]
    per_node: dict[str, int] = {}
    for node, n in zip(nodes, steps, strict=True):
        per_node[node[:8]] = per_node.get(node[:8], 0) + n
    return {"workers": workers, "seconds": round(elapsed, 1), "env_steps": int(sum(steps)),
            "env_steps_per_s": round(sum(steps) / elapsed, 1), "worker_cpu_s": round(cpu, 1),
            "cores_used": round(cpu / elapsed, 2), "env_steps_per_cpu_s": round(sum(steps) / max(cpu, 1e-9), 1),
            "steps_per_worker": steps, "steps_per_node": per_node}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4])
    parser.add_argument("--out", type=Path, default=Path("lab/results/rollout_scaling"))
    args = parser.parse_args()
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import ray
    from ray.cluster_utils import Cluster

    result: dict = {"load_average_start": os.getloadavg(), "cpus": os.cpu_count(), "copies_per_worker": COPIES}
    result["per_step_us"] = {name: round(per_step_us(name), 1) for name in OWN_ENVS}
    slowest = max(result["per_step_us"], key=result["per_step_us"].get)
    result["env"] = slowest
    print(f"per world step (µs): {result['per_step_us']}; slowest: {slowest}", flush=True)
    config = env_config(slowest)
    cpus = config.service.rollout_cpus
    ray.init(address="local", num_cpus=os.cpu_count(), include_dashboard=False, log_to_driver=False)
    try:
        local = [rollout_rate(config, k, args.seconds, cpus) for k in args.workers]
    finally:
        ray.shutdown()
    one = local[0]["env_steps_per_s"]
    for row in local:
        row["ratio_to_1"] = round(row["env_steps_per_s"] / one, 2)
        print(f"{row['workers']} workers: {row['env_steps_per_s']:,.0f} env steps/s, x{row['ratio_to_1']}; "
              f"{row['cores_used']} cores used, {row['env_steps_per_cpu_s']:,.0f} env steps per CPU second "
              f"(per worker {row['steps_per_worker']})", flush=True)
    result["local"] = local
    result["load_average_after_local"] = os.getloadavg()
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    cluster.add_node(num_cpus=1)
    ray.init(address=cluster.address, log_to_driver=False)
    try:
        result["two_nodes"] = rollout_rate(config, 2, args.seconds, 1.0)
        result["two_nodes"]["nodes_alive"] = sum(n["Alive"] for n in ray.nodes())
    finally:
        ray.shutdown()
        cluster.shutdown()
    print(f"2-node cluster, 2 workers of 1 CPU: steps per node {result['two_nodes']['steps_per_node']} "
          f"({result['two_nodes']['env_steps_per_s']:,.0f} env steps/s)", flush=True)
    result["load_average_end"] = os.getloadavg()
    print(f"load average: start {result['load_average_start']}, end {result['load_average_end']}", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / f"{slowest}.json"
    path.write_text(json.dumps({**result, "provenance": provenance()}, indent=1))
    print(f"written: {path}")


if __name__ == "__main__":
    main()

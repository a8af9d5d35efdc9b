"""Our side of the peer comparison: `python -m cmcl train --runner inline` on a peer environment, timed, then scored
by the same held-out evaluation as the AgileRL side (`bench/peer_envs.py`: same seeds, same episodes, the same
return per agent summed over the episode).

Training is the public command, unchanged defaults except what the environment needs:
``env.factory`` / ``env.factory_kwargs`` (the constructor of `peer_envs.ENVS[--env]`), ``env.episode_length`` = the
env's max_cycles, ``teams.agent.algorithm`` = --algorithm, ``run.episodes`` = --env-steps / max_cycles (every
episode lasts max_cycles world steps, so the run takes exactly --env-steps world steps; env.num_envs stays 16 as
AgileRL's), ``run.seed``. Train seconds: the runner's own clock (``elapsed_s`` of the run's summary: training only,
no start-up, as AgileRL's side measures); the wall seconds of the whole command and its CPU seconds
(``RUSAGE_CHILDREN`` user + system: the command is one process, torch set to one thread) are recorded too.

Usage (the repo's venv):

    OMP_NUM_THREADS=1 nice -n 10 .venv/bin/python bench/peer_ours.py --env simple_spread_v3 --algorithm maddpg \
        --env-steps 200000 --seed 0 --eval-episodes 200 --out lab/results/peer_agilerl/ours_maddpg_spread3_seed0.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(1, str(Path(__file__).resolve().parents[1]))
from peer_envs import ENVS, PeerEnv, Policy, eval_seeds, heldout_evaluation, random_policy  # noqa: E402

from cmcl.run.provenance import provenance  # noqa: E402

NUM_ENVS = 16  # env.num_envs, our default and AgileRL's yaml value: worlds stepped at once


def train_command(env_spec: PeerEnv, algorithm: str, env_steps: int, seed: int, run_dir: Path) -> list[str]:
    """The `python -m cmcl train --runner inline` command line of one run."""
    if env_steps % (NUM_ENVS * env_spec.max_cycles):
        raise SystemExit(f"--env-steps {env_steps} must be a multiple of num_envs x episode length "
                         f"({NUM_ENVS} x {env_spec.max_cycles}): the loop steps all {NUM_ENVS} worlds at once")
    kwargs = ", ".join(f"{k} = {json.dumps(v)}" for k, v in env_spec.factory_kwargs)
    sets = [f"env.factory={env_spec.factory}", f"env.factory_kwargs={{{kwargs}}}",
            f"env.episode_length={env_spec.max_cycles}", f"teams.agent.algorithm={algorithm}",
            f"run.episodes={env_steps // env_spec.max_cycles}", f"run.seed={seed}", f"run.dir={run_dir}",
            f"env.num_envs={NUM_ENVS}"]
    return [sys.executable, "-m", "cmcl", "train", "--runner", "inline", "--quiet",
            *[a for s in sets for a in ("--set", s)]]


def trained_policy(run_dir: Path, env_spec: PeerEnv) -> Policy:
    """The run's newest checkpoint as a PettingZoo policy: obs dict -> our actor (no noise) -> each agent's Box."""
    import torch

    from cmcl.envs.factory import describe
    from cmcl.run.evaluate import load_policy
    from cmcl.run.rundir import RunDirectory

    torch.set_num_threads(1)
    run = RunDirectory.open(run_dir)
    config = run.config()
    checkpoint = run.newest_policy()
    if checkpoint is None:
        raise SystemExit(f"no checkpoint in {run_dir}")
    maddpg = load_policy(config, checkpoint)
    env = env_spec.make()
    specs = describe(env)
    env.close()
    obs_dim = max(s.obs_size for s in specs)

    def act(obs):
        batch = np.zeros((1, len(specs), obs_dim), np.float32)
        for i, s in enumerate(specs):
            batch[0, i, : s.obs_size] = np.asarray(obs[s.agent_id], np.float32).ravel()
        a = np.clip(maddpg.act(batch, 0.0)[0], -1.0, 1.0)
        return {s.agent_id: (s.act_low + (a[i, : s.act_size] + 1.0) * 0.5 * (s.act_high - s.act_low))
                .reshape(s.act_shape).astype(np.float32) for i, s in enumerate(specs) if s.agent_id in obs}

    return act


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--env", choices=sorted(ENVS), default="simple_spread_v3")
    ap.add_argument("--algorithm", choices=("maddpg", "cmcl", "per", "acl"), default="maddpg")
    ap.add_argument("--env-steps", type=int, default=200_000, help="world steps (one step of all agents, one env)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--eval-episodes", type=int, default=200)
    ap.add_argument("--run-dir", default="", help="default: runs/peer_<env>_<algorithm>_s<seed>")
    ap.add_argument("--out", default="results.json")
    args = ap.parse_args()

    env_spec = ENVS[args.env]
    run_dir = Path(args.run_dir or f"runs/peer_{args.env}_{args.algorithm}_s{args.seed}")
    cmd = train_command(env_spec, args.algorithm, args.env_steps, args.seed, run_dir)
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    env["PYTHONPATH"] = os.pathsep.join([str(Path(__file__).resolve().parents[1]), env.get("PYTHONPATH", "")])
    load_start = os.getloadavg()
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    load_end = os.getloadavg()
    summary = json.loads((run_dir / "summary.json").read_text())

    seeds = eval_seeds(args.seed, args.eval_episodes)
    ev = heldout_evaluation(env_spec, trained_policy(run_dir, env_spec), seeds)
    rnd = heldout_evaluation(env_spec, random_policy(env_spec, args.seed), seeds)
    result = {
        "library": "cmcl",
        "algorithm": args.algorithm,
        "python": platform.python_version(),
        "env": env_spec.label,
        "seed": args.seed,
        "num_envs": NUM_ENVS,
        "env_steps": int(summary["env_steps"]),
        "env_steps_requested": args.env_steps,
        "train_episodes": int(summary["episodes"]),
        "updates": int(summary["updates"]),
        "train_seconds": float(summary["elapsed_s"]),
        "command_wall_seconds": wall,
        "train_cpu_seconds": (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime),
        "loadavg_1min_start_end": [load_start[0], load_end[0]],
        "train_return_window": summary.get("window", {}).get("reward"),
        "eval_episodes": ev["episodes"],
        "eval_seeds": ev["seeds"],
        "eval_return": ev["return_mean"],
        "eval_return_std": ev["return_std"],
        "random_return": rnd["return_mean"],
        "random_return_std": rnd["return_std"],
        **({"eval_coverage": ev["coverage_mean"], "eval_success": ev["success_rate"]} if "coverage_mean" in ev else {}),
        "eval_returns": ev["returns"],
        "command": cmd[1:],
        "argv": sys.argv[1:],
    }
    line = json.dumps({**result, "provenance": provenance()}, separators=(",", ":"))
    Path(args.out).write_text(line + "\n")
    print(line, flush=True)


if __name__ == "__main__":
    main()

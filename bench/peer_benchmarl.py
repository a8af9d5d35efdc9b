"""Peer measurement: BenchMARL 1.5.2 (MAPPO or MADDPG, BenchMARL's own yaml defaults, no tuning) on our sparse
navigation task, for a wall-clock budget.

What it runs
------------
Env: ``peer_envs.ENVS["sparse_spread"]`` = ``cmcl.envs.sparse_spread_v0.parallel_env(num_agents=4, max_cycles=30,
shared_reward=False)`` -- the env of configs/spread_cmcl.toml (N = 4, 30-step episodes, the run configuration's
individual reward C1 + C2: -1 per contact / wall hit, +4 per covered landmark). It reaches BenchMARL as a custom
task (`SparseSpreadTask`, a subclass of BenchMARL's own PettingZoo task class) whose env function wraps the
ParallelEnv in TorchRL's ``torchrl.envs.libs.pettingzoo.PettingZooWrapper`` (parallel API, one group "agent" of
4 agents, continuous Box(-1, 1, (2,)) actions). The only layer between the two is `CoverageInfo`, which replaces
the env's per-step infos by two float keys (TorchRL builds the info spec from the reset's infos and writes only
those keys each step): ``final_coverage`` / ``final_success`` = the final step's ``info["episode"]`` values (0 on
other steps). Nothing else (observations, rewards, dones) is touched.

Algorithm and settings: ``benchmarl.algorithms.MappoConfig`` / ``MaddpgConfig`` ``.get_from_yaml()``,
``ExperimentConfig.get_from_yaml()`` and ``MlpConfig.get_from_yaml()`` for actor and critic, i.e. BenchMARL's
shipped defaults (lr 5e-5, 6000 frames per batch from 10 envs, MAPPO 45 minibatch iterations of 400, MADDPG
1000 optimizer steps of 128 per batch, MLP 256-256 Tanh, parameter sharing on). Changed only: CPU devices,
no loggers / evaluation / rendering / json / checkpoints (they would cost wall clock and need wandb), and
max_n_frames large (the wall-clock budget stops the run).

Budget and counting: the clock starts when ``experiment.run()`` starts (set-up excluded, as on the AgileRL side);
a callback checks it after every collected batch and stops the run (the last batch is not trained on) once
``--seconds`` have passed. Every collected batch (6000 world steps = 200 episodes of 30 steps) gives its finished
episodes' final-step coverage; their end time is the batch's collection time, so the time resolution of
"time to MA 0.9" is one batch. ``env_steps`` counts world steps (one step of all 4 agents in one env copy).

Install (a venv of its own, torch stays the local CPU wheel): ``make peer-benchmarl``; see docs/PERFORMANCE.md
"BenchMARL peer (set-up)".

Usage:

    OMP_NUM_THREADS=1 nice -n 10 .venv-benchmarl/bin/python bench/peer_benchmarl.py --algorithm mappo \
        --seconds 300 --seed 0 --out lab/results/peer_benchmarl/mappo_seed0.json

Prints progress lines, then a one-line JSON summary (also written to --out).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")
os.environ.setdefault("WANDB_MODE", "disabled")

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(1, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402
import torch  # noqa: E402
from benchmarl.environments.pettingzoo.common import PettingZooClass  # noqa: E402
from benchmarl.experiment.callback import Callback  # noqa: E402
from peer_envs import ENVS, ForwardingWrapper  # noqa: E402
from torchrl.envs.libs.pettingzoo import PettingZooWrapper  # noqa: E402

from cmcl.run.provenance import provenance  # noqa: E402

ENV = ENVS["sparse_spread"]  # --env sets it (an env of ENVS whose final step reports coverage and success)
MA_WINDOW = 100
MA_TARGET = 0.9


class CoverageInfo(ForwardingWrapper):
    """Per-agent infos = {final_coverage, final_success}: the final step's info["episode"] values, else 0.0."""

    INFO = {"final_coverage": 0.0, "final_success": 0.0}

    def reset(self, seed=None, options=None):
        obs, infos = self.env.reset(seed=seed, options=options)
        return obs, {a: dict(self.INFO) for a in infos}

    def step(self, actions):
        obs, rew, terms, truncs, infos = self.env.step(actions)
        out = dict(self.INFO)
        for info in infos.values():
            if "episode" in info:
                out = {"final_coverage": float(info["episode"]["coverage"]),
                       "final_success": float(bool(info["episode"]["success"]))}
                break
        return obs, rew, terms, truncs, {a: dict(out) for a in infos}


class SparseSpreadTask(PettingZooClass):
    """A BenchMARL task of our env, through TorchRL's PettingZooWrapper (see the module docstring)."""

    def get_env_fun(self, num_envs, continuous_actions, seed, device):
        return lambda: PettingZooWrapper(env=CoverageInfo(ENV.make()), categorical_actions=True, device=device,
                                         seed=seed, return_state=False, use_mask=False)

    def supports_continuous_actions(self) -> bool:
        return True

    def supports_discrete_actions(self) -> bool:
        return False

    def has_state(self) -> bool:
        return False

    def has_render(self, env) -> bool:
        return False

    def max_steps(self, env) -> int:
        return ENV.max_cycles

    @staticmethod
    def env_name() -> str:
        return "cmcl_sparse_spread"


class BudgetReached(Exception):
    """Raised by the callback to end experiment.run() at the wall-clock budget."""


class Track(Callback):
    """After every collected batch: its finished episodes' final-step coverage, the MA curve, the budget check.

    Module-level (BenchMARL pickles its callbacks). state["t0"] is set by main when experiment.run() starts."""

    def __init__(self, budget_seconds: float) -> None:
        super().__init__()
        self.budget = budget_seconds
        self.cov: list[float] = []
        self.succ: list[float] = []
        self.ends: list[float] = []
        self.curve: list[dict] = []
        self.state: dict = {"t0": None, "frames": 0, "batches": 0}

    def on_batch_collected(self, batch):
        state, cov = self.state, self.cov
        t = time.perf_counter() - state["t0"]
        flat = batch.reshape(-1)
        done = flat.get(("next", "done")).reshape(-1)
        fc = flat.get(("next", "agent", "info", "final_coverage"))[..., 0].reshape(-1)
        fs = flat.get(("next", "agent", "info", "final_success"))[..., 0].reshape(-1)
        idx = torch.nonzero(done).reshape(-1)
        cov.extend(fc[idx].tolist())
        self.succ.extend(fs[idx].tolist())
        self.ends.extend([t] * int(idx.numel()))
        state["frames"] += int(flat.numel())
        state["batches"] += 1
        ma = float(np.mean(cov[-MA_WINDOW:])) if cov else None  # None (JSON null) until an episode ends
        self.curve.append({"seconds": round(t, 2), "episodes": len(cov), "env_steps": state["frames"],
                           "ma100_coverage": ma})
        print(f"t={t:7.1f}s batch={state['batches']} episodes={len(cov)} env_steps={state['frames']} "
              f"ma100_coverage={'-' if ma is None else f'{ma:.3f}'}", flush=True)
        if t >= self.budget:
            raise BudgetReached


def first_ma_crossing(values, times, window, threshold):
    """1-based episode index (and its seconds) where the `window`-episode moving average first reaches threshold."""
    if len(values) < window:
        return None, None
    c = np.cumsum(np.asarray(values, dtype=np.float64))
    ma = (c[window - 1:] - np.concatenate([[0.0], c[:-window]])) / window
    hits = np.nonzero(ma >= threshold - 1e-12)[0]
    if hits.size == 0:
        return None, None
    k = int(hits[0]) + window
    return k, float(times[k - 1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--algorithm", choices=("mappo", "maddpg"), default="mappo")
    ap.add_argument("--seconds", type=float, default=300.0, help="wall-clock training budget")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--frames-per-batch", type=int, default=None,
                    help="override BenchMARL's collected frames per batch (on- and off-policy, default 6000); for "
                         "smoke tests only (a deviation from the defaults, recorded in the summary)")
    ap.add_argument("--out", default=None, help="JSON summary (default lab/results/peer_benchmarl/"
                                                "<algorithm>_seed<seed>.json)")
    ap.add_argument("--env", choices=[name for name, env in ENVS.items() if env.has_coverage], default="sparse_spread",
                    help="the task (peer_envs.ENVS; vacl_n4: VACL's all-or-nothing navigation, docs/SPARSE_TASKS.md)")
    args = ap.parse_args()
    global ENV
    ENV = ENVS[args.env]
    out = Path(args.out or Path(__file__).resolve().parents[1] / "lab" / "results" / "peer_benchmarl"
               / f"{args.algorithm}_seed{args.seed}.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)

    from importlib.metadata import version as pkg_version

    from benchmarl.algorithms import MaddpgConfig, MappoConfig
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models.mlp import MlpConfig

    algo_cfg = (MappoConfig if args.algorithm == "mappo" else MaddpgConfig).get_from_yaml()
    cfg = ExperimentConfig.get_from_yaml()
    cfg.sampling_device = cfg.train_device = cfg.buffer_device = "cpu"
    cfg.loggers = []
    cfg.evaluation = False
    cfg.render = False
    cfg.create_json = False
    cfg.checkpoint_interval = 0
    cfg.checkpoint_at_end = False
    cfg.max_n_frames = 10**10
    cfg.max_n_iters = None
    if args.frames_per_batch:
        cfg.on_policy_collected_frames_per_batch = cfg.off_policy_collected_frames_per_batch = args.frames_per_batch
    save_dir = tempfile.mkdtemp(prefix="benchmarl_")
    cfg.save_folder = save_dir

    track = Track(args.seconds)
    cov, succ, ends, curve, state = track.cov, track.succ, track.ends, track.curve, track.state

    t_setup = time.perf_counter()
    task = SparseSpreadTask("SPARSE_SPREAD", {"max_cycles": ENV.max_cycles})
    experiment = Experiment(task=task, algorithm_config=algo_cfg, model_config=MlpConfig.get_from_yaml(),
                            critic_model_config=MlpConfig.get_from_yaml(), seed=args.seed, config=cfg,
                            callbacks=[track])
    setup_seconds = time.perf_counter() - t_setup
    print(f"benchmarl {pkg_version('benchmarl')} torchrl {pkg_version('torchrl')} tensordict "
          f"{pkg_version('tensordict')} torch {torch.__version__} algorithm={args.algorithm} seed={args.seed} "
          f"budget={args.seconds}s setup={setup_seconds:.1f}s", flush=True)
    state["t0"] = time.perf_counter()
    cpu0 = time.process_time()
    stopped_by = "budget"
    try:
        experiment.run()
        stopped_by = "max_n_frames"
    except BudgetReached:
        pass
    train_seconds = time.perf_counter() - state["t0"]
    cpu = time.process_time() - cpu0

    k, s = first_ma_crossing(cov, ends, MA_WINDOW, MA_TARGET)
    summary = {
        "peer": f"benchmarl.{args.algorithm}",
        "library": "benchmarl",
        "algorithm": args.algorithm,
        "versions": {p: pkg_version(p) for p in ("benchmarl", "torchrl", "tensordict", "torch", "pettingzoo")},
        "python": platform.python_version(),
        "env": ENV.label,
        "env_wrapper": "torchrl.envs.libs.pettingzoo.PettingZooWrapper(CoverageInfo(env)), custom BenchMARL task",
        "seed": args.seed,
        "budget_seconds": args.seconds,
        "frames_per_batch_override": args.frames_per_batch,
        "stopped_by": stopped_by,
        "setup_seconds": setup_seconds,
        "train_seconds": train_seconds,
        "train_cpu_seconds_main": cpu,
        "env_steps": state["frames"],
        "train_episodes": len(cov),
        "batches": state["batches"],
        "ma100_coverage_0.9_episode": k,
        "ma100_coverage_0.9_seconds": s,
        "ma100_coverage_final": float(np.mean(cov[-MA_WINDOW:])) if cov else None,
        "ma100_coverage_max": (max(c["ma100_coverage"] for c in curve if c["episodes"] >= MA_WINDOW)
                               if len(cov) >= MA_WINDOW else None),
        "train_success_ma100_final": float(np.mean(succ[-MA_WINDOW:])) if succ else None,
        "ma100_coverage_curve": curve,
        "hyperparameters": {"algorithm": {k2: v for k2, v in vars(algo_cfg).items() if not k2.startswith("_")},
                            "experiment": {k2: getattr(cfg, k2) for k2 in (
                                "gamma", "lr", "share_policy_params", "on_policy_collected_frames_per_batch",
                                "on_policy_n_envs_per_worker", "on_policy_n_minibatch_iters",
                                "on_policy_minibatch_size", "off_policy_collected_frames_per_batch",
                                "off_policy_n_envs_per_worker", "off_policy_n_optimizer_steps",
                                "off_policy_train_batch_size", "off_policy_memory_size")},
                            "model": "MlpConfig.get_from_yaml() (actor and critic)"},
        "torch_threads": torch.get_num_threads(),
        "loadavg_1min_end": os.getloadavg()[0],
        "argv": sys.argv[1:],
    }
    line = json.dumps({**summary, "provenance": provenance()}, separators=(",", ":"), default=str)
    out.write_text(line + "\n")
    print(line, flush=True)


if __name__ == "__main__":
    main()

"""Learning evidence: inline runs of several algorithms × seeds on one task, evaluated against a random policy.

Trains with the inline runner (the service's roles in this process, `services.launch.train_in_process`) for every
(algorithm, seed) in turn (one process, one torch thread), evaluates the final policy checkpoint without exploration
noise on held-out worlds, and prints a table of mean ± std across seeds.
Nothing here is a claim by itself: read the spread across seeds.

    python lab/studies/learning_evidence.py --algorithms cmcl maddpg --seeds 0 1 2 --episodes 600 --out runs/evidence
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from cmcl.config import load_config
from cmcl.run.evaluate import evaluate_policy, load_policy
from cmcl.run.plots import plot_learning_curves
from cmcl.run.provenance import provenance
from cmcl.run.rundir import RunDirectory
from services.launch import train_in_process


def run_one(task: str, algorithm: str, seed: int, episodes: int, out: Path, overrides: list[str]) -> dict:
    """Train one inline run (or reuse a finished one in the same folder) and evaluate its final checkpoint."""
    run_path = out / f"{task}_{algorithm}_s{seed}"
    sets = [f"run.episodes={episodes}", f"run.seed={seed}", f"run.dir={run_path}", *overrides]
    config = load_config(f"configs/{task}_{algorithm}.toml", sets)
    started = time.perf_counter()
    if RunDirectory(run_path).summary().get("episodes", 0) < episodes:  # else reuse the finished run
        run_dir = RunDirectory.create(run_path, config, overwrite=True)
        summary, _ = train_in_process(config, run_dir,
                                      progress=lambda line: print(f"  [{algorithm} s{seed}] {line}", flush=True))
        run_dir.write_summary({**{k: v for k, v in summary.items() if k != "metrics_text"}, "runner": "inline"})
    policy = RunDirectory.open(run_path).newest_policy()
    result = evaluate_policy(config, load_policy(config, policy), episodes=200, seed=seed)
    result.update(algorithm=algorithm, seed=seed, train_seconds=time.perf_counter() - started)
    return result


def summarise(results: list[dict], key: str) -> str:
    """'mean ± std (min..max)' of results[key] across seeds."""
    v = np.array([r[key] for r in results], dtype=np.float64)
    return f"{v.mean():.3f} ± {v.std(ddof=1) if v.size > 1 else 0.0:.3f} ({v.min():.3f}..{v.max():.3f})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--task", default="spread", choices=["spread", "tag"])
    parser.add_argument("--algorithms", nargs="+", default=["cmcl", "maddpg"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--episodes", type=int, default=600)
    parser.add_argument("--out", default="runs/evidence")
    parser.add_argument("--set", dest="overrides", action="append", default=[])
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    key = "coverage" if args.task == "spread" else "predator_win"
    table: dict[str, list[dict]] = {}
    for algorithm in args.algorithms:
        table[algorithm] = [run_one(args.task, algorithm, s, args.episodes, out, args.overrides) for s in args.seeds]
    config = load_config(f"configs/{args.task}_{args.algorithms[0]}.toml")
    table["random"] = [evaluate_policy(config, None, episodes=200, seed=s) for s in args.seeds]
    (out / "results.json").write_text(json.dumps({**table, "provenance": provenance()}, indent=2))
    runs = [out / f"{args.task}_{a}_s{s}" for a in args.algorithms for s in args.seeds]
    plot_learning_curves(runs, out / "learning_curves.png", window=50)
    print(f"\n{args.task}: {args.episodes} training episodes, seeds {args.seeds}, 200 evaluation episodes each")
    print(f"{'policy':10s} {key + ' (final step)':34s} {'success':34s} reward")
    for name, results in table.items():
        success = summarise(results, "success") if "success" in results[0] else "-"
        rewards = {t: round(float(np.mean([r["reward"][t] for r in results])), 2) for t in results[0]["reward"]}
        print(f"{name:10s} {summarise(results, key):34s} {success:34s} {rewards}")


if __name__ == "__main__":
    main()

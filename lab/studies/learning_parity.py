"""Learning parity: the distributed service vs the inline loop, same config, same env steps, several seeds.

One rollout worker and 1:1 ratios (one learner update per env step, one teacher / ICM step per update) are the
service defaults. Each (mode, seed) run is evaluated on the same 200 held-out worlds without exploration noise.
Inline runs are shared with lab/studies/learning_evidence.py (a finished run in the same folder is reused).

    python lab/studies/learning_parity.py --seeds 0 1 2 --episodes 1000 --out runs/evidence
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from learning_evidence import run_one, summarise  # noqa: E402

from cmcl.config import load_config  # noqa: E402
from cmcl.run.evaluate import evaluate_policy, load_policy  # noqa: E402
from cmcl.run.provenance import provenance  # noqa: E402
from cmcl.run.rundir import RunDirectory  # noqa: E402


def run_service_one(task: str, algorithm: str, seed: int, episodes: int, out: Path, overrides: list[str]) -> dict:
    """Train one service run on an embedded Ray and evaluate its final learner checkpoint."""
    import ray

    from services.launch import run_service

    run_path = out / f"{task}_{algorithm}_s{seed}_service"
    sets = [f"run.episodes={episodes}", f"run.seed={seed}", f"run.dir={run_path}", "service.metrics_port=0",
            *overrides]
    config = load_config(f"configs/{task}_{algorithm}.toml", sets)
    started = time.perf_counter()
    if not (run_path / "learning_done").exists():
        run_dir = RunDirectory.create(run_path, config, overwrite=True)
        ray.init(address="local", include_dashboard=False, log_to_driver=False)
        try:
            summary = run_service(config, run_dir, progress=lambda line: print(f"  [service s{seed}] {line}",
                                                                               flush=True))
        finally:
            ray.shutdown()
        (run_path / "learning_done").write_text(json.dumps({k: v for k, v in summary.items()
                                                            if k != "metrics_text"}))
    policy = load_policy(config, RunDirectory.open(run_path).newest_policy())
    result = evaluate_policy(config, policy, episodes=200, seed=seed)
    result.update(mode="service", seed=seed, train_seconds=time.perf_counter() - started)
    return result


def inline_result(args: argparse.Namespace, seed: int, out: Path) -> dict:
    """The inline run's evaluation: from learning_evidence's results.json when it holds this seed, else a new run."""
    saved = out / "results.json"
    if saved.exists():
        for result in json.loads(saved.read_text()).get(args.algorithm, []):
            if result.get("seed") == seed:
                return result
    return run_one(args.task, args.algorithm, seed, args.episodes, out, args.overrides)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--task", default="spread", choices=["spread", "tag"])
    parser.add_argument("--algorithm", default="cmcl")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--out", default="runs/evidence")
    parser.add_argument("--set", dest="overrides", action="append", default=[])
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    table = {"inline": [inline_result(args, s, out) for s in args.seeds], "service": []}
    for seed in args.seeds:
        table["service"].append(run_service_one(args.task, args.algorithm, seed, args.episodes, out, args.overrides))
        r = table["service"][-1]
        print(f"service seed {seed}: coverage {r.get('coverage', float('nan')):.3f} "
              f"win {r.get('predator_win', float('nan')):.3f} ({r['train_seconds']:.0f}s)", flush=True)
    (out / f"parity_{args.task}_{args.algorithm}.json").write_text(
        json.dumps({**table, "provenance": provenance()}, indent=2))
    key = "coverage" if args.task == "spread" else "predator_win"
    print(f"\n{args.task} {args.algorithm}: {args.episodes} episodes per run, seeds {args.seeds}, 200 eval episodes")
    for mode, results in table.items():
        print(f"{mode:8s} {key} {summarise(results, key)}   reward "
              f"{[round(sum(r['reward'].values()), 1) for r in results]}")


if __name__ == "__main__":
    main()

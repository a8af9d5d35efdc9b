"""What the service's checkpoint cadence costs in learner updates/s: the same run with checkpoints every
`--cadence` seconds against checkpoints only at the end, alternated in one process on the same machine.

A checkpoint drains every call in flight, then every role saves (learner, teachers, ICM, replay snapshot): the
pipeline stalls meanwhile. Printed per arm: steady updates/s (bench/service_throughput.steady_rates), the number
of checkpoints and their mean and max wall seconds; then the ratio of updates/s (cadence / none) and the stall
fraction each arm spent checkpointing, and what that stall would be at the default cadence
(service.checkpoint_every_s). Alternating the arms (A B A B ...) keeps a drift of the machine's load out of the
ratio. The default cadence's cost target: <= 3 % of updates/s.

    python bench/checkpoint_cadence.py [--cadence 10] [--seconds 90] [--pairs 2]
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from service_throughput import steady_rates  # noqa: E402

from cmcl.config import ServiceConfig, load_config  # noqa: E402
from cmcl.run.rundir import RunDirectory  # noqa: E402

NEVER_S = 1e9  # a cadence no run reaches: one checkpoint, at the end


def run_once(cadence_s: float, seconds: float, out: Path) -> dict[str, float]:
    """One embedded-Ray service run of `seconds` with checkpoints every `cadence_s`; its rates and checkpoints."""
    import ray

    from services.launch import run_service

    config = load_config(ROOT / "configs" / "spread_cmcl.toml",
                         [f"run.dir={out}", f"run.max_seconds={seconds}", "service.metrics_port=0",
                          f"service.checkpoint_every_s={cadence_s}"])
    run = RunDirectory.create(out, config, overwrite=True)
    ray.init(address="local", include_dashboard=False, log_to_driver=False)
    try:
        summary = run_service(config, run, progress=None)
    finally:
        ray.shutdown()
    periodic = summary["checkpoint_seconds"][:-1]  # the last one is the end-of-run checkpoint, in both arms
    return {**steady_rates(run), "checkpoints": len(periodic),
            "stall_s": sum(periodic), "mean_s": statistics.mean(periodic) if periodic else 0.0,
            "max_s": max(periodic, default=0.0), "elapsed_s": summary["elapsed_s"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cadence", type=float, default=10.0, help="seconds between checkpoints in the tested arm")
    parser.add_argument("--seconds", type=float, default=90.0, help="training seconds per run")
    parser.add_argument("--pairs", type=int, default=2, help="A/B pairs, alternated")
    parser.add_argument("--out", default="runs/bench_checkpoint_cadence")
    args = parser.parse_args()
    out = Path(args.out)
    shutil.rmtree(out, ignore_errors=True)
    arms: dict[str, list[dict[str, float]]] = {"none": [], f"every {args.cadence:g} s": []}
    for pair in range(args.pairs):
        for (name, runs), cadence in zip(arms.items(), (NEVER_S, args.cadence), strict=True):
            runs.append(run_once(cadence, args.seconds, out / f"{name.replace(' ', '_')}_{pair}"))
            r = runs[-1]
            print(f"pair {pair} {name:>14s}: {r['updates_per_s']:7.1f} updates/s, {r['checkpoints']} checkpoints, "
                  f"mean {r['mean_s']:.2f} s, max {r['max_s']:.2f} s", flush=True)
    none, tested = arms.values()
    ratio = statistics.mean(t["updates_per_s"] for t in tested) / statistics.mean(n["updates_per_s"] for n in none)
    per_checkpoint = statistics.mean(t["mean_s"] for t in tested)
    default = ServiceConfig().checkpoint_every_s
    print(f"updates/s ratio, every {args.cadence:g} s / none: {ratio:.3f} ({args.pairs} pairs of {args.seconds:g} s)")
    print(f"stall per checkpoint: {per_checkpoint:.2f} s mean; at {args.cadence:g} s that is "
          f"{per_checkpoint / args.cadence:.1%} of the wall clock, at the default {default:g} s "
          f"{per_checkpoint / default:.1%}")


if __name__ == "__main__":
    main()

"""Cost per update of every registered sampling rule, inline, against MADDPG's in the same process (issue 36).

For each rule of the registry (cmcl.algorithms), the inline loop of the default navigation preset with
`teams.agent.algorithm=<rule>`, its 5000-row buffer filled by the policy; then rounds of `InlineLoop.update()`
interleaved across the rules (the machine is shared), the median seconds per update reported with its ratio to
MADDPG's. An update is everything the loop does per update at the defaults: teacher and ICM steps where the rule
needs them, scoring and rescoring, the priority recompute, the candidates' critic pass (LaBER), the MADDPG step.

Run: .venv/bin/python bench/rule_cost.py [--rounds 5] [--updates 20]   (prints one line per rule, then JSON)
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.learner_throughput import filled_loop  # noqa: E402
from cmcl.algorithms import ALGORITHMS  # noqa: E402
from cmcl.provenance import provenance  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--updates", type=int, default=20)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    loops = {name: filled_loop("maddpg", [f"teams.agent.algorithm={name}"]) for name in ALGORITHMS}
    seconds: dict[str, list[float]] = {name: [] for name in loops}
    for _ in range(args.rounds):
        for name, loop in loops.items():
            t0 = time.perf_counter()
            for _ in range(args.updates):
                loop.update()
            seconds[name].append((time.perf_counter() - t0) / args.updates)
    per = {name: statistics.median(v) for name, v in seconds.items()}
    for name in ALGORITHMS:
        print(f"{name:8s} {1e3 * per[name]:7.2f} ms per update   ratio to maddpg {per[name] / per['maddpg']:.2f}")
    print(json.dumps({"ms_per_update": {k: round(1e3 * v, 3) for k, v in per.items()},
                      "ratio_to_maddpg": {k: round(v / per["maddpg"], 3) for k, v in per.items()},
                      "rounds": args.rounds, "updates": args.updates, "provenance": provenance()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())

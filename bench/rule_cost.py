"""Cost per update of every registered sampling rule, in one process, against MADDPG's in the same process.

For each rule of the registry (cmcl.replay.registry), the service's roles of the default navigation preset with
`teams.agent.algorithm=<rule>` built in this process (as `--runner inline` runs them: bench/learner_throughput.py
`FilledRoles`), the 5000-row buffer filled by the policy; then rounds of about `--updates` learner updates
interleaved across the rules (the machine is shared), the median seconds per update reported with its ratio to
MADDPG's. An update is everything the roles do per update at the defaults: teacher and ICM steps where the rule
needs them with their scoring calls, the priority recompute, the candidates' critic pass (LaBER), the MADDPG step.

Options of a rule are measured as arms of their own beside the rules (`OPTIONS`): per+uniform_actor is PER with
`teams.agent.actor_batch="uniform"` (the actor's own uniform minibatch), its ratio to per printed too.

Run: .venv/bin/python bench/rule_cost.py [--rounds 5] [--updates 20] [--arms per per+uniform_actor]
     (prints one line per arm, then JSON; --arms: these arms only, with maddpg and the rules of the options named)
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
from cmcl.replay.registry import ALGORITHMS  # noqa: E402
from cmcl.run.provenance import provenance  # noqa: E402

# an option of a rule -> (the rule, its overrides): measured beside the rules, its ratio to the rule printed too
OPTIONS = {"per+uniform_actor": ("per", ['teams.agent.actor_batch="uniform"'])}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--updates", type=int, default=20)
    parser.add_argument("--arms", nargs="+", choices=[*ALGORITHMS, *OPTIONS], help="these arms only")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    arms = {name: (name, []) for name in ALGORITHMS} | OPTIONS
    if args.arms:
        kept = {"maddpg", *args.arms, *(OPTIONS[a][0] for a in args.arms if a in OPTIONS)}
        arms = {name: arm for name, arm in arms.items() if name in kept}
    loops = {name: filled_loop("maddpg", [f"teams.agent.algorithm={rule}", *extra])
             for name, (rule, extra) in arms.items()}
    seconds: dict[str, list[float]] = {name: [] for name in loops}
    for _ in range(args.rounds):
        for name, loop in loops.items():
            t0, done = time.perf_counter(), 0
            while done < args.updates:  # in learner calls of service.updates_per_call updates
                done += loop.update()
            seconds[name].append((time.perf_counter() - t0) / done)
    per = {name: statistics.median(v) for name, v in seconds.items()}
    for name in arms:
        print(f"{name:8s} {1e3 * per[name]:7.2f} ms per update   ratio to maddpg {per[name] / per['maddpg']:.2f}")
    to_rule = {name: round(per[name] / per[rule], 3) for name, (rule, _) in OPTIONS.items() if name in per}
    for name, ratio in to_rule.items():
        print(f"{name} ratio to {OPTIONS[name][0]} {ratio:.2f}")
    print(json.dumps({"ms_per_update": {k: round(1e3 * v, 3) for k, v in per.items()},
                      "ratio_to_maddpg": {k: round(v / per["maddpg"], 3) for k, v in per.items()},
                      "ratio_to_rule": to_rule,
                      "rounds": args.rounds, "updates": args.updates, "provenance": provenance()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The holder rule swapped under trained policies, without training (maddpg.holder_rule).

Runs trained with the holder margin under the "nearest" rule (every other agent counts as holding a landmark) are
evaluated on the same held-out worlds as `python -m cmcl evaluate RUN --episodes 200` (seed 0), once as trained and
once with the actor reading the margin under the "seated" rule (an agent seated on a landmark holds only that one,
cmcl.learners.entity.holder). The weights are the run's; only the feature changes, so this says whether the trained
policies already act on a landmark whose only holder sits on another landmark, before any training under the rule.
Per run and rule: coverage, success and the miss anatomy (cmcl.run.stalls: worlds with an uncovered landmark, and worlds
with every landmark covered but not each by an agent of its own).

Run:  .venv/bin/python lab/studies/holder_rule_transfer.py RUN [RUN ...] [--episodes 200] [--out FILE.json]
Output: one line per run and rule; the JSON holds the same numbers and the provenance of the code.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from cmcl.run.evaluate import evaluate_policy, load_policy  # noqa: E402
from cmcl.run.provenance import provenance  # noqa: E402
from cmcl.run.rundir import RunDirectory  # noqa: E402

RULES = ("nearest", "seated")


def evaluate_rules(run_dir: str, episodes: int) -> dict[str, dict]:
    """{rule: evaluate_policy's result} for the run's newest verified policy under each rule."""
    run = RunDirectory.open(run_dir)
    config = run.config()
    if not config.maddpg.entity_holder:
        raise SystemExit(f"error: {run_dir} was trained without the holder margin (maddpg.entity_holder = false)")
    policy = run.newest_policy()
    if policy is None:
        raise SystemExit(f"error: {run_dir} holds no policy checkpoint that passes its checks")
    out = {}
    for rule in RULES:
        maddpg = load_policy(config, policy)
        maddpg.actor.holder_rule = rule
        result = evaluate_policy(config, maddpg, episodes, seed=0)
        out[rule] = {"coverage": result["coverage"], "success": result["success"], "misses": result["misses"],
                     "agents": maddpg.num_agents, "checkpoint": str(policy.path)}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("runs", nargs="+", help="run directories trained with maddpg.entity_holder = true")
    parser.add_argument("--episodes", type=int, default=200, help="held-out worlds per run and rule")
    parser.add_argument("--out", help="write the numbers as JSON here")
    args = parser.parse_args(argv)
    started, results = time.time(), {}
    for run_dir in args.runs:
        results[run_dir] = evaluate_rules(run_dir, args.episodes)
        for rule, r in results[run_dir].items():
            m = r["misses"]
            print(f"{run_dir} N={r['agents']} {rule:8s} coverage {r['coverage']:.3f} success {r['success']:.3f} | "
                  f"a landmark uncovered {m['missed_share']:.3f}, every landmark covered but not each by its own "
                  f"agent {m['covered_unmatched_share']:.3f}", flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps({
            "command": "lab/studies/holder_rule_transfer.py " + " ".join(sys.argv[1:]), "episodes": args.episodes,
            "seconds": round(time.time() - started, 1), "runs": results,
            "provenance": provenance()}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

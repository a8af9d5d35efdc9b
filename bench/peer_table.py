"""The peer table: one row per (library, algorithm, env steps) from the result files of `bench/peer_agilerl.py` and
`bench/peer_ours.py` on one environment.

Columns: held-out return (the return per agent summed over the episode, `bench/peer_envs.py`; mean over seeds, then
each seed), the random policy's return on the same held-out episodes (mean over seeds), the training seconds (the
training loop's wall clock) and the CPU seconds of training (AgileRL: main process + vec-env workers; ours: the
one training process), each seed.

Usage:  python bench/peer_table.py [--env simple_spread_v3] [lab/results/peer_agilerl/*.json]
"""

from __future__ import annotations

import argparse
import glob
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

LABEL = {"agilerl": "AgileRL 2.58", "cmcl": "ours (inline)"}
ENV_PREFIX = {"simple_spread_v3": "mpe2.simple_spread_v3", "sparse_spread": "sparse_spread_v0"}


def load(paths: list[str], env: str) -> dict[tuple[str, str, int], list[dict]]:
    """Result rows of `env` grouped by (library, algorithm, env_steps), each group sorted by seed."""
    groups: dict[tuple[str, str, int], list[dict]] = defaultdict(list)
    for path in paths:
        row = json.loads(Path(path).read_text())
        if "eval_return" not in row or not row["env"].startswith(ENV_PREFIX[env]):
            continue
        groups[(row["library"], row["algorithm"], int(row["env_steps"]))].append(row)
    return {k: sorted(v, key=lambda r: r["seed"]) for k, v in sorted(groups.items())}


def joined(values: list[float], spec: str) -> str:
    """'1.0, 2.0' for values [1, 2] and spec '.1f'."""
    return ", ".join(format(v, spec) for v in values)


def table(groups: dict[tuple[str, str, int], list[dict]]) -> str:
    """The markdown table."""
    lines = ["| library | algorithm | env steps | seeds | held-out return: mean (each seed) | random policy's return "
             "| train wall s (each seed) | CPU s (each seed) |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for (library, algorithm, steps), rows in groups.items():
        ret = [r["eval_return"] for r in rows]
        lines.append(
            f"| {LABEL.get(library, library)} | {algorithm.upper() if algorithm != 'cmcl' else 'CMCL'} | {steps:,} "
            f"| {', '.join(str(r['seed']) for r in rows)} "
            f"| **{np.mean(ret):.1f}** ({joined(ret, '.1f')}) "
            f"| {np.mean([r['random_return'] for r in rows]):.1f} "
            f"| {joined([r['train_seconds'] for r in rows], '.0f')} "
            f"| {joined([r['train_cpu_seconds'] for r in rows], '.0f')} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--env", choices=sorted(ENV_PREFIX), default="simple_spread_v3")
    ap.add_argument("paths", nargs="*")
    args = ap.parse_args()
    results = Path(__file__).resolve().parents[1] / "lab" / "results" / "peer_agilerl"
    paths = args.paths or sorted(glob.glob(str(results / "*.json")))
    print(table(load(paths, args.env)))


if __name__ == "__main__":
    main()

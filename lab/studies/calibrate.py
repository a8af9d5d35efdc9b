"""Calibrate a harder sparse navigation task: MADDPG inline on candidate variants within the
paper's description, one seed each, one run at a time, until one reaches a 100-episode moving-average coverage of
about 0.5 around the middle of its budget (neither at floor nor at ceiling).

Each candidate is a list of ``--set`` overrides on configs/spread_maddpg.toml. For each run: the moving average of
the training final-step coverage at 25/50/75/100 % of the budget, the uniform random policy's held-out coverage on
the same variant (200 worlds), and the wall seconds of training. One JSON per run in ``<out>/<id>.json``; a rerun
skips the runs that have one.

    python -m lab.studies.calibrate --candidates n6 r005 n8 --episodes 20000 --seed 0
    python -m lab.studies.calibrate --table
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from cmcl.config import load_config
from cmcl.io.atomic import atomic_write_bytes
from cmcl.run.evaluate import evaluate_policy
from cmcl.run.rundir import RunDirectory
from experiments.grids import RESULTS
from experiments.measures import WINDOW
from experiments.run_spec import ROOT
from experiments.runner import die_with_parent

CANDIDATES = {  # name -> --set overrides of configs/spread_maddpg.toml (every other value: the shared defaults)
    "n4": [],  # the current task, for reference
    "n6": ["env.num_agents=6"],
    "n8": ["env.num_agents=8"],
    "r005": ["env.cover_radius=0.05"],  # N = 4, landmark cover radius halved
    "r0075": ["env.cover_radius=0.075"],
    "n6_r0075": ["env.num_agents=6", "env.cover_radius=0.075"],
}
FRACTIONS = (0.25, 0.5, 0.75, 1.0)


def moving_average_at(coverage: np.ndarray, budget: int, fractions=FRACTIONS) -> list[float | None]:
    """The trailing WINDOW-episode mean of coverage float[T] at each fraction of `budget` episodes (None before
    WINDOW episodes, and past the episodes the run has: a MADDPG run's first T episodes do not depend on its
    budget, so a shorter run measures the start of a longer one)."""
    out = []
    for f in fractions:
        end = int(round(f * budget))
        ok = WINDOW <= end <= coverage.size + WINDOW // 2  # a batched run may stop a few episodes short or over
        out.append(round(float(coverage[end - WINDOW:end].mean()), 4) if ok else None)
    return out


def calibrate(name: str, seed: int, episodes: int, out: Path, budget: int) -> dict:
    """Train one candidate (subprocess, inline MADDPG) and measure it; returns the stored record."""
    run_id = f"{name}_s{seed}_e{episodes}"
    run_path = out / "runs" / run_id
    sets = [*CANDIDATES[name], f"run.seed={seed}", f"run.episodes={episodes}", f"run.dir={run_path}"]
    started = time.perf_counter()
    subprocess.run([sys.executable, "-m", "cmcl", "train", "--runner", "inline", "--config",
                    str(ROOT / "configs" / "spread_maddpg.toml"),
                    *[a for s in sets for a in ("--set", s)], "--overwrite", "--quiet"], cwd=ROOT, check=True,
                   stdout=subprocess.DEVNULL, preexec_fn=die_with_parent())
    rows = list(RunDirectory.open(run_path).rows("episode"))
    coverage = np.array([r["coverage"] for r in rows], dtype=np.float64)
    config = load_config(ROOT / "configs" / "spread_maddpg.toml", [*CANDIDATES[name], "run.dir=unused"])
    record = {"id": run_id, "candidate": name, "sets": CANDIDATES[name], "seed": seed, "episodes": int(coverage.size),
              "budget": budget, "ma_coverage_at": dict(zip([f"{int(f * 100)}%" for f in FRACTIONS],
                                                           moving_average_at(coverage, budget), strict=True)),
              "random_coverage": round(float(evaluate_policy(config, None, 200, seed=1)["coverage"]), 4),
              "wall_s": round(float(rows[-1].get("elapsed_s", np.nan)), 1),
              "process_s": round(time.perf_counter() - started, 1),
              "curve": np.round(coverage[: coverage.size // WINDOW * WINDOW].reshape(-1, WINDOW).mean(1), 4).tolist()}
    atomic_write_bytes(out / f"{run_id}.json", json.dumps(record).encode())
    return record


def table(out: Path) -> str:
    """The calibration table (markdown) of every record in `out`."""
    lines = ["| setting | seed | episodes | MA coverage at 25 / 50 / 75 / 100 % of the budget | random policy's "
             "coverage | wall s |", "| --- " * 6 + "|"]
    for path in sorted(out.glob("*.json")):
        r = json.loads(path.read_text())
        ma = " / ".join("—" if v is None else f"{v:.3f}" for v in r["ma_coverage_at"].values())
        setting = ", ".join(r["sets"]) or "defaults (N = 4, cover radius 0.1)"
        lines.append(f"| {r['candidate']}: {setting} | {r['seed']} | {r['episodes']:,} | {ma} | "
                     f"{r['random_coverage']:.3f} | {r['wall_s']:.0f} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--candidates", nargs="+", choices=list(CANDIDATES), default=["r005", "n6", "n8"])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--episodes", type=int, default=20_000, help="episodes to train (at most --budget)")
    parser.add_argument("--budget", type=int, default=20_000, help="the budget the fractions refer to")
    parser.add_argument("--out", default=str(RESULTS / "calibration"))
    parser.add_argument("--table", action="store_true", help="print the table of what has finished, train nothing")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.table:
        print(table(out))
        return
    for name in args.candidates:
        if (out / f"{name}_s{args.seed}_e{args.episodes}.json").exists():
            continue
        r = calibrate(name, args.seed, args.episodes, out, args.budget)
        print(f"{r['id']}: MA coverage at 25/50/75/100 % {list(r['ma_coverage_at'].values())}, random "
              f"{r['random_coverage']}, {r['wall_s']} s", flush=True)


if __name__ == "__main__":
    main()

"""What the agent-count curriculum's learning-progress signal looks like, stage by stage (issue 38, run.stop_progress).

`run.stop_progress` ends a stage once LP_k = |δ̄_k − δ̄_{k−1}| / δ̄_{k−1} (cmcl/learning_progress.py: δ̄_k the mean
critic loss of episode window k) stays below the threshold for `run.progress_patience` windows. At 0.05 over three
500-episode windows it never fired. This runs the stages with the rule off (`python -m cmcl stages`, inline, the
scale grid's `n8_entity_stages` settings: MADDPG, entity networks) and prints, per stage and window: the mean critic
loss, LP, and the window's mean final-step coverage, so the rule can be set from what LP does while coverage still
rises and after it flattens.

Run:  .venv/bin/python bench/learning_progress_windows.py [--agents 2 4] [--stage-episodes 3000 5000] [--seed 0]
      [--out bench/results/scale/learning_progress_windows.json]
Output: one table per stage; the JSON holds the same numbers and the provenance of the code.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cmcl.io.checkpoint_files import load_checkpoint  # noqa: E402
from cmcl.io.rundir import RunDirectory  # noqa: E402
from cmcl.provenance import provenance  # noqa: E402

SETTINGS = ["maddpg.networks=entity", "run.stop_progress=0", "run.max_seconds=0"]  # the n8_entity_stages cell, rule off


def stage_windows(run_dir: Path, window: int) -> list[dict[str, float]]:
    """Per finished window of one stage's run: episodes at its end, mean critic loss δ̄_k, LP_k (None for the
    first), mean final-step coverage of its episodes."""
    run = RunDirectory.open(run_dir)
    state = load_checkpoint(run.latest_checkpoint())
    lp = state["learning_progress"]
    coverage = np.array([r["coverage"] for r in run.rows() if r.get("kind") == "episode"])
    first = int(lp["window_index"]) - len(lp["means"])  # the means are of the closed windows just before the open one
    out = []
    for k, mean in enumerate(lp["means"]):
        w = first + k
        out.append({"episodes": (w + 1) * window, "critic_loss": float(mean),
                    "lp": None if k == 0 else float(lp["progress"][k - 1]),
                    "coverage": float(coverage[w * window:(w + 1) * window].mean())})
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--agents", type=int, nargs="+", default=[2, 4])
    parser.add_argument("--stage-episodes", type=int, nargs="+", default=[3000, 5000])
    parser.add_argument("--window", type=int, default=500, help="run.progress_window (episodes)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="bench/results/scale/learning_progress_windows.json", help="'' = none")
    args = parser.parse_args(argv)
    sets = [*SETTINGS, f"run.progress_window={args.window}", f"run.seed={args.seed}"]
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "stages"
        cmd = [sys.executable, "-m", "cmcl", "stages", "--agents", *map(str, args.agents), "--stage-episodes",
               *map(str, args.stage_episodes), "--runner", "inline", "--config", "configs/spread_maddpg.toml",
               "--quiet", "--no-eval", *[a for s in [*sets, f"run.dir={root}"] for a in ("--set", s)]]
        code = provenance()  # the code as imported, before the run
        done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
        if done.returncode != 0:
            print(done.stdout[-2000:], done.stderr[-2000:], sep="\n", file=sys.stderr)
            return 1
        stages = {n: stage_windows(root / f"n{n}", args.window) for n in args.agents}
    for n, windows in stages.items():
        print(f"N = {n}: window end | mean critic loss | LP | mean coverage")
        for w in windows:
            lp = "—" if w["lp"] is None else f"{w['lp']:.3f}"
            print(f"  {w['episodes']:>6} | {w['critic_loss']:.4f} | {lp:>6} | {w['coverage']:.3f}")
    if args.out:
        out = ROOT / args.out
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps({"command": " ".join(["bench/learning_progress_windows.py", *(argv or sys.argv[1:])]),
                                   "stages_command": " ".join(cmd[1:]).replace(str(root), "<tmp>"),
                                   "stages": {str(n): w for n, w in stages.items()}, "provenance": code},
                                  indent=1) + "\n")
        print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""What the agent-count curriculum's learning-progress signals look like, stage by stage (run.stop_progress).

`run.stop_progress` ends a stage once the learning progress of `run.progress_signal` (cmcl/progress/learning.py)
stays below the threshold for `run.progress_patience` windows. The old signal, the relative change of the mean
critic loss LP_k = |δ̄_k − δ̄_{k−1}| / δ̄_{k−1}, never fired at 0.05 over three 500-episode windows: the critic loss
grows with the value scale. This runs the stages with the rule off (`python -m cmcl stages`, inline, the scale
grid's `n8_entity_stages` settings: MADDPG, entity networks) and prints, per stage and window, all three signals the
runners feed it: the mean critic loss and its relative change (raw LP), the mean normalised TD error (the critic's
mean squared TD error over its targets' variance, 1 − R²) and its relative change (normalised-TD LP), and the mean
final-step coverage and its absolute change; then, per signal and threshold, the window at whose end the rule
(patience `run.progress_patience`) would have fired in each stage, so the rule can be set from what each signal does
while coverage still rises and after it flattens. A stage's last full window is closed at the stage's end; the few
episodes its last batched step adds past the budget (3,008 for 3,000 with 16 worlds) are left out.

Run:  .venv/bin/python lab/studies/learning_progress_windows.py [--agents 2 4] [--stage-episodes 3000 5000] [--seed 0]
      [--patience 3] [--out lab/results/scale/learning_progress_windows.json]
Output: one table per stage and the firing table; the JSON holds the same numbers and the provenance of the code.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from cmcl.io.checkpoint_files import load_checkpoint  # noqa: E402
from cmcl.progress.learning import SIGNALS, LearningProgress  # noqa: E402
from cmcl.run.provenance import provenance  # noqa: E402
from cmcl.run.rundir import RunDirectory  # noqa: E402

SETTINGS = ["maddpg.networks=entity", "run.stop_progress=0", "run.max_seconds=0"]  # the n8_entity_stages cell, rule off
THRESHOLDS = {"critic_loss": (0.05, 0.1, 0.2), "normalised_td": (0.02, 0.05, 0.1, 0.2),
              "coverage": (0.005, 0.01, 0.02, 0.05)}  # the thresholds the firing table tries, per signal
COLUMNS = {"critic_loss": "raw LP", "normalised_td": "norm-TD LP", "coverage": "cov change"}


def stage_windows(run_dir: Path, window: int) -> list[dict[str, float | None]]:
    """Per full window of one stage's run (its last closed at the stage's end): episodes at its end, and per signal its
    mean and learning progress ("<signal>", "<signal>_lp"; None for a signal's first window or where it had none),
    from the learning-progress record of the stage's newest checkpoint."""
    run = RunDirectory.open(run_dir)
    lp = LearningProgress(window=window)
    lp.load_state_dict(load_checkpoint(sorted(run.checkpoints.glob("ckpt_*.pt"))[-1])["learning_progress"])
    coverage = np.array([r["coverage"] for r in run.rows() if r.get("kind") == "episode"])
    if len(coverage) >= (lp.window_index + 1) * window:  # the open window is full: close it (a partial one, the
        lp.close()  # few episodes of the last batched step past the budget, is left out)
    out = lp.windows()
    for w in out:  # the runner's record of the coverage is the episode rows' own
        rows = coverage[w["window"] * window:(w["window"] + 1) * window].mean()
        assert abs(rows - w["coverage"]) < 1e-9, (w, rows)
    return out


def first_firing(windows: list[dict[str, float | None]], signal: str, threshold: float, patience: int) -> int | None:
    """The episodes at the end of the window where `patience` consecutive windows of `signal`'s learning progress
    below `threshold` first ended the stage; None if never."""
    below = 0
    for w in windows:
        lp = w[f"{signal}_lp"]
        if lp is None:
            continue
        below = below + 1 if lp < threshold else 0
        if below >= patience:
            return int(w["episodes"])
    return None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--agents", type=int, nargs="+", default=[2, 4])
    parser.add_argument("--stage-episodes", type=int, nargs="+", default=[3000, 5000])
    parser.add_argument("--window", type=int, default=500, help="run.progress_window (episodes)")
    parser.add_argument("--patience", type=int, default=3, help="run.progress_patience of the firing table")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="lab/results/scale/learning_progress_windows.json", help="'' = none")
    args = parser.parse_args(argv)
    sets = [*SETTINGS, f"run.progress_window={args.window}", f"run.seed={args.seed}"]
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "stages"
        cmd = [sys.executable, "-m", "cmcl", "stages", "--agents", *map(str, args.agents), "--stage-episodes",
               *map(str, args.stage_episodes), "--runner", "inline", "--config", "configs/spread_maddpg.toml",
               "--quiet", "--no-eval", *[a for s in [*sets, f"run.dir={root}"] for a in ("--set", s)]]
        code = provenance()  # the code as imported, before the run
        started = time.perf_counter()
        done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
        seconds = time.perf_counter() - started
        if done.returncode != 0:
            print(done.stdout[-2000:], done.stderr[-2000:], sep="\n", file=sys.stderr)
            return 1
        stages = {n: stage_windows(root / f"n{n}", args.window) for n in args.agents}
    fmt = lambda x, spec: "—" if x is None else format(x, spec)  # noqa: E731
    for n, windows in stages.items():
        print(f"N = {n}: window end | coverage | cov change | critic loss | raw LP | norm. TD | norm-TD LP")
        for w in windows:
            print(f"  {w['episodes']:>6} | {fmt(w['coverage'], '.3f'):>8} | {fmt(w['coverage_lp'], '.3f'):>10} | "
                  f"{fmt(w['critic_loss'], '.4f'):>11} | {fmt(w['critic_loss_lp'], '.3f'):>6} | "
                  f"{fmt(w['normalised_td'], '.4f'):>8} | {fmt(w['normalised_td_lp'], '.3f'):>10}")
    firing = {signal: {str(t): {str(n): first_firing(windows, signal, t, args.patience)
                                for n, windows in stages.items()} for t in THRESHOLDS[signal]} for signal in SIGNALS}
    print(f"the rule (patience {args.patience}) would end the stage at episode (— never):")
    for signal, by_threshold in firing.items():
        for t, by_stage in by_threshold.items():
            print(f"  {COLUMNS[signal]:>10} < {t:<5} " + "  ".join(f"N = {n}: {fmt(e, 'd'):>5}"
                                                                for n, e in by_stage.items()))
    if args.out:
        out = ROOT / args.out
        out.parent.mkdir(parents=True, exist_ok=True)
        study = "lab/studies/learning_progress_windows.py"
        out.write_text(json.dumps({"command": " ".join([study, *(argv or sys.argv[1:])]),
                                   "stages_command": " ".join(cmd[1:]).replace(str(root), "<tmp>"),
                                   "seconds": round(seconds, 1), "patience": args.patience,
                                   "stages": {str(n): w for n, w in stages.items()}, "firing": firing,
                                   "provenance": code}, indent=1) + "\n")
        print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

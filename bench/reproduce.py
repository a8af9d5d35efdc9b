"""Reproduce the paper's comparisons: a resumable grid of (task, algorithm per team, seed) runs at the paper's budget.

Grids (the shared defaults of cmcl/config/ for every algorithm, 20,000 episodes each, no early stop):

* ``spread``: sparse cooperative navigation N=4 with maddpg, per, acl and cmcl (the paper's Figs. 8-9);
* ``tag``: predator-prey, predators learning with each algorithm against MADDPG prey (Fig. 12);
* ``winrate``: CMCL predators against ACL prey and against PER-MADDPG prey (Fig. 13);
* ``ablations``: CMCL on navigation with one setting changed at a time (ABLATIONS below; the unchanged CMCL runs
  of ``spread`` are their reference: η = 0.5, K = 5, the default normalisation, the default λ stride, IS off);
* ``curriculum`` (issue 21, the pre-registered protocol of docs/RESULTS.md): navigation N=4 with the arms of
  CURRICULUM_ARMS -- maddpg, per, acl, cmcl, and CMCL's two controls, ``cmcl_permuted`` (its priorities shuffled
  across rows: same ESS, no information) and ``cmcl_anti`` (difficulty reversed) -- all at the same shared defaults
  (rank difficulty, α_s = 1 for ACL / CMCL and 0.6 for PER), progress rows every 200 episodes so that the summary
  holds the sampling distribution's ESS and reward-row shares over training;
* ``curriculum_hard``: the same arms on the calibrated harder navigation of configs/spread_hard.toml (cover radius
  0.075; MADDPG's moving-average coverage is about 0.5 at the middle of its budget).

Runs are ordered seed outermost (seed 0 of every arm, then seed 1, ...), so a grid stopped part-way has balanced
arms. A run that fails is reported and the grid goes on; a rerun retries it.

Every run trains in its own subprocess (``python -m cmcl.loop``, inline) and checkpoints every 2,000 episodes.
A rerun skips the runs whose summary exists and resumes an interrupted one from its latest checkpoint (its clock
goes on from the checkpoint, so seconds stay comparable). Each finished run writes ``<out>/summaries/<id>.json``
(measures, held-out evaluation, and 100-episode window curves, a few KB), and ``<out>/results.csv`` is rebuilt
from all summaries. The figures and tables come from ``bench/reproduce_report.py``.

    python bench/reproduce.py --grid spread --seeds 0 1 2 3 4 --jobs 2
    python bench/reproduce.py --grid tag winrate --seeds 0 1 2 3 4
    python bench/reproduce.py --grid curriculum --seeds 0 1 2 3 4 5 6 7 8 9 --jobs 2
    python bench/reproduce_report.py      # tables (mean ± 95% CI), tests, figures, into docs/RESULTS.md's inputs
"""

from __future__ import annotations

import argparse
import csv
import ctypes
import json
import os
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cmcl.config import ALGORITHMS  # noqa: E402
from cmcl.evaluate import evaluate_policy, load_policy  # noqa: E402
from cmcl.io.atomic import atomic_write_bytes  # noqa: E402
from cmcl.io.plots import episode_series  # noqa: E402
from cmcl.io.rundir import RunDirectory  # noqa: E402

sys.path.insert(0, str(ROOT / "bench"))
from time_to_solve import WINDOW, first_reaching  # noqa: E402  (the one moving-average threshold rule of both benches)

EPISODES, TARGETS, HELD_OUT = 20_000, (0.5, 0.9), 200
CSV_COLUMNS = ("id", "grid", "task", "algorithm", "prey_algorithm", "ablation", "seed", "budget", "episodes",
               "env_steps", "updates", "wall_s", "episodes_to_50", "episodes_to_90", "seconds_to_50", "seconds_to_90",
               "auc_coverage", "final_ma_coverage", "final_ma_success", "mean_reward", "mean_reward_predator",
               "mean_reward_prey", "final_ma_predator_win", "held_out_coverage", "held_out_success",
               "held_out_collisions", "held_out_wall_hits", "win_vs_trained_prey", "win_vs_random_prey",
               "arm", "ess_mean", "ess_first_quarter", "reward_rows_sampled_mean", "reward_rows_buffer_mean")

# arm -> (config file, --set overrides) of the ``curriculum`` grid; every other setting is the shared default
CURRICULUM_ARMS = {
    "maddpg": ("spread_maddpg.toml", []),
    "per": ("spread_per.toml", []),
    "acl": ("spread_acl.toml", []),
    "cmcl": ("spread_cmcl.toml", []),
    "cmcl_permuted": ("spread_cmcl.toml", ["teachers.difficulty_transform=permuted"]),
    "cmcl_anti": ("spread_cmcl.toml", ["teachers.difficulty_transform=reversed"]),
}
HARD_CONFIG = "spread_hard.toml"  # the calibrated harder task (docs/RESULTS.md, "A harder task: calibration")
CURRICULUM_LOG_EVERY = 200  # episodes between progress rows (the ESS curve's resolution) in the curriculum grid


ABLATIONS = {  # name -> (config file, --set overrides, episode budget or None for the grid's) of CMCL variants
    "eta0": ("spread_cmcl.toml", ["teams.agent.eta=0.0"], None),
    "eta1": ("spread_cmcl.toml", ["teams.agent.eta=1.0"], None),
    "k2": ("spread_cmcl.toml", ["teachers.num_folds=2"], None),
    # the default since 2026-12 (A1); kept so its committed 5-seed results (run at the old "max" default) stay named
    "rank": ("spread_cmcl.toml", ["teachers.difficulty_norm=rank"], None),
    "max": ("spread_cmcl.toml", ["teachers.difficulty_norm=max"], None),  # the pre-2026-12 normalisation
    "stride_x2": ("spread_cmcl.toml", ["curriculum.stride=6e-6"], None),  # λ_max at a quarter of training
    "stride_half": ("spread_cmcl.toml", ["curriculum.stride=1.5e-6"], None),  # λ_max at the end
    "is_on": ("spread_cmcl.toml", ["teams.agent.is_correction=true"], None),
    # One update per world step: 16 times the updates (116,176 by episode 4,000), about 35 min a run here, so
    # it runs the first 4,000 episodes only and is compared with the reference runs' first 4,000 episodes
    # (their checkpoint at 4,000; see prefix_reference_runs).
    "paper_schedule": ("paper/spread_cmcl.toml", [], 4_000),
}


def grid(names: list[str], seeds: list[int], algorithms: list[str], budget: int = EPISODES) -> list[dict[str, Any]]:
    """The runs of the grids, seed outermost (every cell has seed k before any has seed k+1):
    [{id, grid, task, algorithm, prey_algorithm, seed, budget (episodes)}]."""
    runs = []
    for seed in seeds:
        for name in names:
            if name in ("curriculum", "curriculum_hard"):
                for arm, (config, sets) in CURRICULUM_ARMS.items():
                    algorithm = arm.split("_")[0]
                    if name == "curriculum_hard":  # the same arms on the harder task: its config, each algorithm
                        config, sets = HARD_CONFIG, [f"teams.agent.algorithm={algorithm}", *sets]
                    runs.append({"id": f"{name}_{arm}_s{seed}", "grid": name, "task": "spread",
                                 "algorithm": algorithm, "prey_algorithm": None, "seed": seed,
                                 "budget": budget, "arm": arm, "config": config,
                                 "sets": [f"run.log_every={CURRICULUM_LOG_EVERY}", *sets]})
                continue
            if name == "ablations":
                for ablation, (config, sets, own_budget) in ABLATIONS.items():
                    runs.append({"id": f"ablation_{ablation}_s{seed}", "grid": name, "task": "spread",
                                 "algorithm": "cmcl", "prey_algorithm": None, "seed": seed,
                                 "budget": min(budget, own_budget or budget), "ablation": ablation,
                                 "config": config, "sets": sets})
                continue
            if name == "spread":
                cells = [("spread", a, None) for a in reversed(algorithms)]  # the longest (cmcl) first
            elif name == "tag":
                cells = [("tag", a, "maddpg") for a in reversed(algorithms)]
            else:
                cells = [("tag", "cmcl", prey) for prey in ("acl", "per")]
            for task, algorithm, prey in cells:
                run_id = f"{task}_{algorithm}_s{seed}" if prey in (None, "maddpg") else \
                    f"{task}_{algorithm}_vs_{prey}_s{seed}"
                runs.append({"id": run_id, "grid": name, "task": task, "algorithm": algorithm,
                             "prey_algorithm": prey, "seed": seed, "budget": budget})
    return list({r["id"]: r for r in runs}.values())


def train(run: dict[str, Any], out: Path) -> Path:
    """Train (or resume) one run in a subprocess; returns its run directory."""
    run_path = out / "runs" / run["id"]
    if run_path.exists() and RunDirectory.open(run_path).latest_checkpoint() is not None:
        cmd = [sys.executable, "-m", "cmcl.loop", "--resume", str(run_path), "--quiet"]
    else:
        sets = [f"run.seed={run['seed']}", f"run.dir={run_path}", f"run.episodes={run['budget']}", "run.log_every=500",
                "run.checkpoint_every=2000"]
        if run["prey_algorithm"] is not None:
            sets.append(f"teams.prey.algorithm={run['prey_algorithm']}")
        sets += run.get("sets", [])
        config_file = ROOT / "configs" / run.get("config", f"{run['task']}_{run['algorithm']}.toml")
        cmd = [sys.executable, "-m", "cmcl.loop", "--config", str(config_file),
               *[a for s in sets for a in ("--set", s)], "--overwrite", "--quiet"]
    subprocess.run(cmd, cwd=ROOT, check=True, stdout=subprocess.DEVNULL, preexec_fn=die_with_parent)
    return run_path


def die_with_parent() -> None:
    """In the child, before exec: ask Linux to SIGKILL it when its parent goes (prctl PR_SET_PDEATHSIG), so a
    killed grid never leaves an orphan training that a rerun's resume would then race on the same run directory."""
    ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # 1 = PR_SET_PDEATHSIG


def window_curves(series: dict[str, np.ndarray]) -> dict[str, list[float]]:
    """Means over consecutive WINDOW-episode windows of every per-episode column: {name: [T // WINDOW]}."""
    n = series["episode"].size // WINDOW * WINDOW
    return {k: np.round(v[:n].reshape(-1, WINDOW).mean(axis=1), 5).tolist()
            for k, v in series.items() if k != "episode"}


def prefix_reference_runs(runs: list[dict[str, Any]], full_budget: int) -> list[dict[str, Any]]:
    """For every ablation run with a smaller budget than the grid's, the unchanged CMCL run of its seed read up to
    that budget (same measures, held-out from its checkpoint at that episode): [{id "reference_e<B>_s<seed>",
    grid "ablation_reference", source (the spread run's id), budget B, ...}]."""
    refs = [{"id": f"reference_e{r['budget']}_s{r['seed']}", "grid": "ablation_reference", "task": "spread",
             "algorithm": "cmcl", "prey_algorithm": None, "seed": r["seed"], "budget": r["budget"],
             "ablation": None, "source": f"spread_cmcl_s{r['seed']}"}
            for r in runs if r.get("grid") == "ablations" and r["budget"] < full_budget]
    return list({r["id"]: r for r in refs}.values())


def summarise(run: dict[str, Any], run_path: Path, upto: int | None = None) -> dict[str, Any]:
    """The measures of one finished run (training curves, time to 0.5/0.9, area, final rates, held-out), or of
    its first `upto` episodes (held-out from its checkpoint at episode `upto`, which must exist)."""
    run_dir = RunDirectory.open(run_path)
    config = run_dir.config()
    rows = list(run_dir.rows("episode"))[:upto]
    series = {k: v[:upto] for k, v in episode_series(run_dir).items()}
    elapsed = np.array([r.get("elapsed_s", np.nan) for r in rows], dtype=np.float64)
    checkpoint = run_dir.latest_checkpoint() if upto is None else run_dir.checkpoint_path(upto)
    if upto is not None and (len(rows) < upto or not checkpoint.exists()):
        raise ValueError(f"{run_path}: no {upto} episodes to read (has {len(rows)}, checkpoint {checkpoint.name} "
                         f"{'exists' if checkpoint.exists() else 'missing'})")
    policy = load_policy(config, checkpoint)
    held_out = evaluate_policy(config, policy, episodes=HELD_OUT, seed=run["seed"])
    last = rows[-1] if upto is not None else list(run_dir.rows("progress"))[-1]
    result: dict[str, Any] = {**run, "episodes": int(series["episode"].size),
                              "env_steps": last["env_steps"], "updates": last["updates"],
                              "wall_s": float(elapsed[-1])}
    if run["task"] == "spread":
        coverage = series["coverage"]
        for target in TARGETS:
            i = first_reaching(coverage, target)
            tag = f"{int(target * 100)}"
            result[f"episodes_to_{tag}"] = None if i is None else i + 1
            result[f"seconds_to_{tag}"] = None if i is None else float(elapsed[i])
        result.update(auc_coverage=float(coverage.mean()), final_ma_coverage=float(coverage[-WINDOW:].mean()),
                      final_ma_success=float(series["success"][-WINDOW:].mean()),
                      mean_reward=float(series["reward_agent"].sum() / run["budget"]),  # Fig. 9's definition (§6.3)
                      held_out_coverage=held_out["coverage"], held_out_success=held_out["success"],
                      held_out_collisions=held_out["collisions"], held_out_wall_hits=held_out["wall_hits"])
    else:
        result.update(mean_reward_predator=float(series["reward_predator"].sum() / run["budget"]),
                      mean_reward_prey=float(series["reward_prey"].sum() / run["budget"]),
                      final_ma_predator_win=float(series["predator_win"][-WINDOW:].mean()),
                      win_vs_trained_prey=held_out["predator_win"],
                      win_vs_random_prey=evaluate_policy(config, policy, HELD_OUT, run["seed"],
                                                         random_teams=("prey",))["predator_win"])
    result["curves"] = window_curves(series)
    result.update(sampling_over_training(list(run_dir.rows("progress")), upto))
    return result


def sampling_over_training(progress: list[dict[str, Any]], upto: int | None = None) -> dict[str, Any]:
    """The sampling distribution over training from a run's progress rows (up to episode `upto`): per row, the mean
    over the agents that do not sample uniformly of the ESS fraction and of the reward-bearing rows' share in the
    sampled minibatch (expected under P) and in the buffer (cmcl.diagnostics.sampling_diagnostics), λ and, for
    ACL / CMCL, the sampling mass on KP's excluded branch. Returns {"sampling_curve": {column: [rows]}, "ess_mean",
    "ess_first_quarter" (rows in the first quarter of the run's episodes), "reward_rows_sampled_mean",
    "reward_rows_buffer_mean"}; a run whose agents all sample uniformly has ESS 1 and sampled = buffer shares."""
    rows = [r for r in progress if r.get("sampling") and (upto is None or r["episodes"] <= upto)]
    curve: dict[str, list] = {k: [] for k in ("episode", "lambda", "ess", "reward_rows_sampled",
                                              "reward_rows_buffer", "share_excluded")}
    for r in rows:
        s = r["sampling"]
        keep = [i for i, m in enumerate(s.get("modes", [])) if m != "uniform"] or list(range(len(s["modes"])))
        curve["episode"].append(r["episodes"])
        curve["lambda"].append(round(r["lambda"], 5))
        for key, name in (("ess", "ess_fraction"), ("reward_rows_sampled", "reward_rows_sampled"),
                          ("reward_rows_buffer", "reward_rows_buffer")):
            curve[key].append(round(float(np.mean([s[name][i] for i in keep])), 4))
        excluded = r.get("curriculum", {}).get("share_excluded")
        curve["share_excluded"].append(None if excluded is None else round(float(np.mean(excluded)), 4))
    last = max(curve["episode"], default=0)
    quarter = [e for ep, e in zip(curve["episode"], curve["ess"], strict=True) if ep <= last / 4]

    def mean(values: list[float]) -> float | None:
        return round(float(np.mean(values)), 4) if values else None

    return {"sampling_curve": curve, "ess_mean": mean(curve["ess"]), "ess_first_quarter": mean(quarter),
            "reward_rows_sampled_mean": mean(curve["reward_rows_sampled"]),
            "reward_rows_buffer_mean": mean(curve["reward_rows_buffer"])}


def write_csv(out: Path) -> Path:
    """Rebuild <out>/results.csv from every summary (one row per finished run; curves left out)."""
    rows = [json.loads(p.read_text()) for p in sorted((out / "summaries").glob("*.json"))]
    path = out / "results.csv"
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=CSV_COLUMNS, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    return path


def run_one(run: dict[str, Any], out: Path) -> str:
    """Train, summarise and store one run (a prefix reference only reads its source run); returns a one-line
    report."""
    started = time.perf_counter()
    if "source" in run:
        summary = summarise(run, out / "runs" / run["source"], upto=run["budget"])
    else:
        summary = summarise(run, train(run, out))
    atomic_write_bytes(out / "summaries" / f"{run['id']}.json", json.dumps(summary).encode())
    keys = ("held_out_coverage", "held_out_success", "episodes_to_90", "win_vs_trained_prey", "wall_s", "ess_mean")
    return f"{run['id']} done in {time.perf_counter() - started:.0f} s: " + \
        ", ".join(f"{k}={summary[k]}" for k in keys if k in summary)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--grid", nargs="+",
                        choices=["spread", "tag", "winrate", "ablations", "curriculum", "curriculum_hard"],
                        default=["spread"])
    parser.add_argument("--arms", nargs="+", choices=list(CURRICULUM_ARMS), default=list(CURRICULUM_ARMS),
                        help="curriculum grid: only these arms")
    parser.add_argument("--ablations", nargs="+", choices=list(ABLATIONS), default=list(ABLATIONS),
                        help="ablations grid: only these variants")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4])
    parser.add_argument("--algorithms", nargs="+", choices=ALGORITHMS, default=list(ALGORITHMS))
    parser.add_argument("--episodes", type=int, default=EPISODES, help="budget of every run (the paper: 20,000)")
    parser.add_argument("--jobs", type=int, default=1, help="runs trained at once (one core each)")
    parser.add_argument("--out", default=str(ROOT / "bench" / "results" / "reproduce"))
    args = parser.parse_args()
    out = Path(args.out)
    (out / "summaries").mkdir(parents=True, exist_ok=True)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    runs = [r for r in grid(args.grid, args.seeds, args.algorithms, args.episodes)
            if r.get("ablation", args.ablations[0]) in args.ablations and r.get("arm", args.arms[0]) in args.arms]
    runs += prefix_reference_runs(runs, args.episodes)
    todo = [r for r in runs if not (out / "summaries" / f"{r['id']}.json").exists()]
    print(f"{len(todo)} runs to do: {' '.join(r['id'] for r in todo)}", flush=True)
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        futures = {pool.submit(run_one, r, out): r["id"] for r in todo}  # submitted in grid order, seed outermost
        for future in as_completed(futures):
            try:
                print(future.result(), flush=True)
            except Exception as err:  # one failed run must not stop the others; a rerun retries it
                print(f"{futures[future]} FAILED: {type(err).__name__}: {err}", flush=True)
            write_csv(out)
    print(f"results: {write_csv(out)}")


if __name__ == "__main__":
    main()

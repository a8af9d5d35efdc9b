"""Time to solve sparse navigation: episodes and seconds until the 100-episode moving average of final-step coverage
reaches 0.9 (and 0.5), then a held-out evaluation, for a grid of runs, inline or on the service.

Grids (every run: sparse navigation N=4, the shared defaults of cmcl/config/, at most 20,000 episodes, stopped
once the moving average reaches --stop-coverage (default 0.95, so that the policy measured on held-out worlds
has gone past the 0.9 it is timed at), and at most --max-seconds of wall clock):

* ``schedule``: MADDPG inline, maddpg.update_every in {1, 4, 16, 64} x maddpg.batch_size in {128, 512};
* ``algorithms``: maddpg, per, acl and cmcl with the defaults, inline and on the embedded service;
* ``tag``: predator-prey, predators learning with each algorithm against MADDPG prey, inline, all 20,000
  episodes (no early stop); evaluated as the predators' win rate against the trained prey, against random prey,
  and random against random.

Every run is its own subprocess (``python -m cmcl.loop`` or ``python -m services.launch``), so each service run
has a fresh embedded Ray. Results go to ``<out>/results.jsonl``, one line per finished run, appended as each
run completes: a rerun skips finished runs and restarts an interrupted one from scratch (runs last minutes).
The held-out evaluation uses the final checkpoint without exploration noise on 200 worlds the run never saw.

    python bench/time_to_solve.py --grid schedule --seeds 0 1 2
    python bench/time_to_solve.py --grid algorithms --seeds 0 1 2 --modes inline service
    python bench/time_to_solve.py --report            # print the tables of what has finished

Seconds are wall clock of training only (evaluation excluded), measured by the run itself from its first step.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cmcl.config import ALGORITHMS, load_config  # noqa: E402
from cmcl.evaluate import evaluate_policy, load_policy  # noqa: E402
from cmcl.io.rundir import PolicyCheckpoint, RunDirectory  # noqa: E402

UPDATE_EVERY = (1, 4, 16, 64)
BATCHES = (128, 512)
WINDOW, TARGETS = 100, (0.5, 0.9)


def grid(name: str, seeds: list[int], modes: list[str], schedule_algorithm: str = "maddpg") -> list[dict[str, Any]]:
    """The runs of a grid: {id, mode, algorithm, seed, sets (extra --set overrides)}."""
    runs = []
    if name == "schedule":  # seed outermost: every configuration has a first seed before any has a second
        for seed in seeds:
            for every in UPDATE_EVERY:
                for batch in BATCHES:
                    runs.append({"id": f"schedule_inline_{schedule_algorithm}_u{every}_b{batch}_s{seed}",
                                 "mode": "inline", "algorithm": schedule_algorithm, "seed": seed,
                                 "update_every": every, "batch_size": batch,
                                 "sets": [f"maddpg.update_every={every}", f"maddpg.batch_size={batch}"]})
    elif name == "tag":
        for seed in seeds:
            for algorithm in reversed(ALGORITHMS):
                runs.append({"id": f"tag_inline_{algorithm}_s{seed}", "mode": "inline", "algorithm": algorithm,
                             "seed": seed, "task": "tag", "sets": []})
    else:
        for seed in seeds:
            for mode in modes:
                for algorithm in reversed(ALGORITHMS):
                    runs.append({"id": f"algorithms_{mode}_{algorithm}_s{seed}", "mode": mode,
                                 "algorithm": algorithm, "seed": seed, "sets": []})
    return runs


def first_reaching(coverage: np.ndarray, target: float) -> int | None:
    """Index of the first episode whose trailing WINDOW-episode mean coverage is >= target (None: never)."""
    if coverage.size < WINDOW:
        return None
    moving = np.convolve(coverage, np.ones(WINDOW) / WINDOW, mode="valid")  # moving[i] ends at episode i+W-1
    hit = np.flatnonzero(moving >= target - 1e-12)
    return int(hit[0]) + WINDOW - 1 if hit.size else None


def solve_times(run_path: Path) -> dict[str, Any]:
    """Episodes and seconds to each coverage target, from the run's episode rows (in order of completion)."""
    rows = list(RunDirectory.open(run_path).rows("episode"))
    coverage = np.array([r["coverage"] for r in rows], dtype=np.float64)
    elapsed = np.array([r.get("elapsed_s", np.nan) for r in rows], dtype=np.float64)
    out: dict[str, Any] = {"episodes": len(rows), "final_ma_coverage": float(coverage[-WINDOW:].mean())}
    for target in TARGETS:
        i = first_reaching(coverage, target)
        tag = f"{int(target * 100)}"
        out[f"episodes_to_{tag}"] = None if i is None else i + 1
        out[f"seconds_to_{tag}"] = None if i is None else float(elapsed[i])
    return out


def win_rates(run_path: Path, config: Any, policy: Any, seed: int, episodes: int = 400) -> dict[str, Any]:
    """Predator-prey: the predators' win rate (>= 1 capture in a round) on held-out worlds against the trained
    prey, against random prey, and of random against random; plus the training moving average at the end."""
    rows = list(RunDirectory.open(run_path).rows("episode"))
    win = np.array([r["predator_win"] for r in rows], dtype=np.float64)
    return {"episodes": len(rows), "final_ma_predator_win": float(win[-WINDOW:].mean()),
            "win_vs_trained_prey": evaluate_policy(config, policy, episodes, seed)["predator_win"],
            "win_vs_random_prey": evaluate_policy(config, policy, episodes, seed, random_teams=("prey",))[
                "predator_win"],
            "random_vs_random": evaluate_policy(config, None, episodes, seed)["predator_win"]}


def train(run: dict[str, Any], out: Path, max_seconds: float, stop_coverage: float) -> tuple[Path, float]:
    """Train one run in a subprocess; returns (run directory, wall seconds of the subprocess)."""
    run_path = out / "runs" / run["id"]
    sets = [f"run.seed={run['seed']}", f"run.dir={run_path}", "run.episodes=20000",
            f"run.stop_coverage={stop_coverage}", f"run.max_seconds={max_seconds}", "run.log_every=200",
            "run.checkpoint_every=0", *run["sets"]]
    config_file = str(ROOT / "configs" / f"{run.get('task', 'spread')}_{run['algorithm']}.toml")
    flags = [a for s in sets for a in ("--set", s)]
    if run["mode"] == "inline":
        cmd = [sys.executable, "-m", "cmcl.loop", "--config", config_file, *flags, "--overwrite", "--quiet"]
    else:
        cmd = [sys.executable, "-m", "services.launch", "--config", config_file, *flags, "--overwrite", "--quiet",
               "--metrics-port", "0"]
    started = time.perf_counter()
    subprocess.run(cmd, cwd=ROOT, check=True, stdout=subprocess.DEVNULL)
    return run_path, time.perf_counter() - started


def final_checkpoint(run_path: Path, mode: str) -> PolicyCheckpoint:
    """The learner weights a run ended with: the run directory's newest verified policy (either runner)."""
    policy = RunDirectory.open(run_path).newest_policy()
    if policy is None:
        raise FileNotFoundError(f"{run_path} ({mode}): no policy checkpoint that passes its checks")
    return policy


def measure(run: dict[str, Any], out: Path, max_seconds: float, stop_coverage: float) -> dict[str, Any]:
    """Train, then time-to-solve from the episode rows, then the held-out evaluation."""
    run_path, wall = train(run, out, max_seconds, stop_coverage)
    config = RunDirectory.open(run_path).config()
    progress = [r for r in RunDirectory.open(run_path).rows("progress")]
    policy = load_policy(config, final_checkpoint(run_path, run["mode"]))
    held_out = evaluate_policy(config, policy, episodes=200, seed=run["seed"])
    if config.env.task == "tag":
        return {**{k: v for k, v in run.items() if k != "sets"}, **win_rates(run_path, config, policy, run["seed"]),
                "wall_s": wall, "env_steps": progress[-1]["env_steps"] if progress else None}
    result = {**{k: v for k, v in run.items() if k != "sets"}, **solve_times(run_path), "wall_s": wall,
              "env_steps": progress[-1]["env_steps"] if progress else None,
              "updates": progress[-1]["updates"] if progress else None,
              "update_every": config.maddpg.update_every, "batch_size": config.maddpg.batch_size,
              "stop_coverage": stop_coverage, "max_seconds": max_seconds,
              "held_out": {k: held_out[k] for k in ("coverage", "success", "collisions", "wall_hits")}}
    return result


def load_results(out: Path) -> dict[str, dict[str, Any]]:
    path = out / "results.jsonl"
    if not path.exists():
        return {}
    return {r["id"]: r for r in map(json.loads, path.read_text().splitlines()) if r}


def spread(values: list[float | None], fmt: str = "{:.0f}") -> str:
    """'mean (min..max)' over seeds; runs that never reached the target are counted and shown as 'n/k never'."""
    got = [v for v in values if v is not None]
    never = len(values) - len(got)
    if not got:
        return f"never ({never}/{len(values)})"
    text = fmt.format(np.mean(got)) + (f" ({fmt.format(min(got))}..{fmt.format(max(got))})" if len(got) > 1 else "")
    return text + (f", {never}/{len(values)} never" if never else "")


def report(results: dict[str, dict[str, Any]]) -> str:
    """Markdown tables, one row per configuration, spread over its seeds."""
    groups: dict[tuple, list[dict[str, Any]]] = {}
    for r in (r for r in results.values() if r.get("task", "spread") == "spread"):
        groups.setdefault((r["id"].split("_")[0], r["mode"], r["algorithm"], r["update_every"], r["batch_size"]),
                          []).append(r)
    lines = ["| grid | mode | algorithm | update_every | batch | seeds | episodes to MA 0.9 | seconds to MA 0.9 | "
             "episodes to MA 0.5 | held-out coverage | held-out success | collisions | wall hits |",
             "| --- " * 13 + "|"]
    for key in sorted(groups):
        rs = sorted(groups[key], key=lambda r: r["seed"])
        h = [r["held_out"] for r in rs]
        lines.append(
            f"| {key[0]} | {key[1]} | {key[2]} | {key[3]} | {key[4]} | {','.join(str(r['seed']) for r in rs)} | "
            f"{spread([r['episodes_to_90'] for r in rs])} | {spread([r['seconds_to_90'] for r in rs])} | "
            f"{spread([r['episodes_to_50'] for r in rs])} | {spread([x['coverage'] for x in h], '{:.3f}')} | "
            f"{spread([x['success'] for x in h], '{:.2f}')} | {spread([x['collisions'] for x in h], '{:.2f}')} | "
            f"{spread([x['wall_hits'] for x in h], '{:.2f}')} |")
    tag = sorted((r for r in results.values() if r.get("task") == "tag"), key=lambda r: (r["algorithm"], r["seed"]))
    if tag:
        lines += ["", "| predators | seeds | win vs trained MADDPG prey | win vs random prey | random vs random | "
                  "training MA win at the end | seconds |", "| --- " * 7 + "|"]
        for algorithm in sorted({r["algorithm"] for r in tag}):
            rs = [r for r in tag if r["algorithm"] == algorithm]
            lines.append(f"| {algorithm} | {','.join(str(r['seed']) for r in rs)} | "
                         + " | ".join(spread([r[k] for r in rs], "{:.3f}") for k in
                                      ("win_vs_trained_prey", "win_vs_random_prey", "random_vs_random",
                                       "final_ma_predator_win"))
                         + f" | {spread([r['wall_s'] for r in rs])} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--grid", choices=["schedule", "algorithms", "tag"], default="algorithms")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--modes", nargs="+", choices=["inline", "service"], default=["inline", "service"])
    parser.add_argument("--algorithms", nargs="+", choices=ALGORITHMS, default=list(ALGORITHMS))
    parser.add_argument("--update-every", nargs="+", type=int, default=list(UPDATE_EVERY),
                        help="schedule grid: only these maddpg.update_every values")
    parser.add_argument("--batch-size", nargs="+", type=int, default=list(BATCHES),
                        help="schedule grid: only these maddpg.batch_size values")
    parser.add_argument("--skip", nargs="*", default=[], help="run ids to leave out")
    parser.add_argument("--schedule-algorithm", choices=ALGORITHMS, default="maddpg",
                        help="schedule grid: the algorithm swept (maddpg; cmcl to confirm the choice)")
    parser.add_argument("--max-seconds", type=float, default=900.0, help="wall-clock cap of one run's training")
    parser.add_argument("--stop-coverage", type=float, default=0.95, help="moving-average coverage that ends a run")
    parser.add_argument("--out", default=str(ROOT / "bench" / "results" / "time_to_solve"))
    parser.add_argument("--report", action="store_true", help="only print the tables of finished runs")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if not args.report:
        todo = [r for r in grid(args.grid, args.seeds, args.modes, args.schedule_algorithm)
                if r["algorithm"] in args.algorithms
                and r.get("update_every", args.update_every[0]) in args.update_every
                and r.get("batch_size", args.batch_size[0]) in args.batch_size and r["id"] not in args.skip]
        for run in todo:
            if run["id"] in load_results(out):
                continue
            print(f"running {run['id']}", flush=True)
            result = measure(run, out, args.max_seconds, args.stop_coverage)
            with (out / "results.jsonl").open("a") as f:
                f.write(json.dumps(result) + "\n")
            print(f"  {run['id']}: {json.dumps(result)}", flush=True)
    random = evaluate_policy(load_config(str(ROOT / "configs" / "spread_maddpg.toml")), None, episodes=200)
    print(report(load_results(out)))
    print(f"random policy, held-out coverage {random['coverage']:.3f}, success {random['success']:.2f}")


if __name__ == "__main__":
    main()

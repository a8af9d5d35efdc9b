"""The measures of one run, read from its run directory: the summary the results store keeps.

Training curves are the per-episode rows of the run (`RunDirectory.rows("episode")`); "MA x" is the first episode
at which the trailing WINDOW-episode moving average of the final-step coverage (predator-prey: of the predators'
win, an episode with a capture) reaches x; the area under a training curve is its mean over the run's episodes.
Held-out: the final weights (or those of the checkpoint at episode `upto`) without exploration noise on HELD_OUT
worlds the run never saw (`cmcl.run.evaluate.evaluate_policy`, seeded by the run's seed).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from cmcl.run.evaluate import evaluate_policy, load_policy
from cmcl.run.plots import episode_series
from cmcl.run.rundir import RunDirectory
from experiments.own_envs import own_env_measures
from experiments.run_spec import Run

WINDOW, TARGETS, HELD_OUT = 100, (0.5, 0.9), 200  # moving-average episodes; coverage thresholds; held-out worlds


def first_reaching(coverage: np.ndarray, target: float) -> int | None:
    """Index of the first episode whose trailing WINDOW-episode mean coverage is >= target (None: never).
    coverage: float[T], one final-step coverage (or predator win, 0/1) per episode in order of completion."""
    if coverage.size < WINDOW:
        return None
    moving = np.convolve(coverage, np.ones(WINDOW) / WINDOW, mode="valid")  # moving[i] ends at episode i+W-1
    hit = np.flatnonzero(moving >= target - 1e-12)
    return int(hit[0]) + WINDOW - 1 if hit.size else None


def times_to_targets(curve: np.ndarray, elapsed: np.ndarray, prefix: str) -> dict[str, int | float | None]:
    """Episodes and seconds until the curve's moving average first reaches each of TARGETS: {"episodes_to_<prefix>50",
    "seconds_to_<prefix>50", ...}, None where never. curve, elapsed: float[T], one per episode."""
    out: dict[str, int | float | None] = {}
    for target in TARGETS:
        i = first_reaching(curve, target)
        tag = f"{prefix}{int(target * 100)}"
        out[f"episodes_to_{tag}"] = None if i is None else i + 1
        out[f"seconds_to_{tag}"] = None if i is None else float(elapsed[i])
    return out


def window_curves(series: dict[str, np.ndarray]) -> dict[str, list[float]]:
    """Means over consecutive WINDOW-episode windows of every per-episode column: {name: [T // WINDOW]}."""
    n = series["episode"].size // WINDOW * WINDOW
    return {k: np.round(v[:n].reshape(-1, WINDOW).mean(axis=1), 5).tolist()
            for k, v in series.items() if k != "episode"}


def summarise(run: Run, run_path: Path, upto: int | None = None) -> dict[str, Any]:
    """The measures of one finished run (training curves, time to 0.5/0.9, area, final rates, held-out), or of
    its first `upto` episodes (held-out from its checkpoint at episode `upto`, which must exist). The run's own
    fields (Run.record) come first."""
    earlier = [RunDirectory.open(run_path / f"n{n}") for n in run.stages[:-1]]
    run_dir = RunDirectory.open(run_path / f"n{run.stages[-1]}" if run.stages else run_path)
    config = run_dir.config()
    rows = list(run_dir.rows("episode"))[:upto]
    progress = list(run_dir.rows("progress"))
    series = {k: v[:upto] for k, v in episode_series(run_dir).items()}
    elapsed = np.array([r.get("elapsed_s", np.nan) for r in rows], dtype=np.float64)
    if upto is None:
        checkpoint = run_dir.newest_policy()
        if checkpoint is None:
            raise FileNotFoundError(f"{run_path}: no policy checkpoint that passes its checks")
    else:
        checkpoint = run_dir.checkpoints / f"ckpt_{upto:08d}.pt"  # the inline runner's own format of older runs
        if len(rows) < upto or not checkpoint.exists():
            raise ValueError(f"{run_path}: no {upto} episodes to read (has {len(rows)}, checkpoint "
                             f"{checkpoint.name} {'exists' if checkpoint.exists() else 'missing'})")
    policy = load_policy(config, checkpoint)
    held_out = evaluate_policy(config, policy, episodes=HELD_OUT, seed=run.seed)
    last = rows[-1] if upto is not None else (progress[-1] if progress else rows[-1])
    result: dict[str, Any] = {**run.record(), "episodes": int(series["episode"].size),
                              "env_steps": last.get("env_steps"), "updates": last.get("updates"),
                              "wall_s": float(elapsed[-1]), "update_every": config.maddpg.update_every,
                              "batch_size": config.maddpg.batch_size}
    if run.task == "own_env":
        result.update(own_env_measures(config, policy, series, held_out, HELD_OUT, run.seed))
    elif run.task == "spread":
        coverage = series["coverage"]
        result.update(times_to_targets(coverage, elapsed, ""))
        result.update(auc_coverage=float(coverage.mean()), final_ma_coverage=float(coverage[-WINDOW:].mean()),
                      final_ma_success=float(series["success"][-WINDOW:].mean()),
                      mean_reward=float(series["reward_agent"].sum() / run.budget),  # Fig. 9's definition (§6.3)
                      held_out_coverage=held_out["coverage"], held_out_success=held_out["success"],
                      held_out_collisions=held_out["collisions"], held_out_wall_hits=held_out["wall_hits"])
    else:  # predator-prey: the predators' capture rate ("win") stands where navigation has coverage
        win = series["predator_win"]
        result.update(times_to_targets(win, elapsed, "win_"))
        result.update(auc_predator_win=float(win.mean()),
                      mean_reward_predator=float(series["reward_predator"].sum() / run.budget),
                      mean_reward_prey=float(series["reward_prey"].sum() / run.budget),
                      final_ma_predator_win=float(series["predator_win"][-WINDOW:].mean()),
                      win_vs_trained_prey=held_out["predator_win"],
                      win_vs_random_prey=evaluate_policy(config, policy, HELD_OUT, run.seed,
                                                         random_teams=("prey",))["predator_win"])
    if run.stages:  # the curriculum's whole cost: every stage's episodes and seconds
        result["stage_costs"] = [stage_cost(d) for d in (*earlier, run_dir)]
        result["total_episodes"] = sum(c["episodes"] for c in result["stage_costs"])
        result["total_wall_s"] = sum(c["wall_s"] for c in result["stage_costs"])
    result["curves"] = window_curves(series)
    result.update(sampling_over_training(progress, upto))
    result.update(intrinsic_over_training(progress, upto))
    return result


def intrinsic_over_training(progress: list[dict[str, Any]], upto: int | None = None) -> dict[str, Any]:
    """Curiosity's reward over training from a run's progress rows (up to episode `upto`), for a run with
    `icm.intrinsic_reward_coef > 0` (its rows carry `intrinsic_reward`, the mean coef·ρ of the learner's last update
    over the agents' own rows, reward units per step): {"intrinsic_reward_first_tenth": the mean over the rows within
    the run's first 10 % of learner updates (the number the sparse confirmation scales its frozen-ICM control by,
    docs/SPARSE_TASKS.md), "intrinsic_reward_mean": over every row, "intrinsic_curve": {"updates": [rows],
    "intrinsic_reward": [rows]}}; {} for a run without it."""
    rows = [r for r in progress if "intrinsic_reward" in r and (upto is None or r["episodes"] <= upto)]
    if not rows:
        return {}
    tenth = 0.1 * max(int(r.get("updates", 0)) for r in rows)
    early = [r["intrinsic_reward"] for r in rows if int(r.get("updates", 0)) <= tenth] or [rows[0]["intrinsic_reward"]]
    return {"intrinsic_reward_first_tenth": round(float(np.mean(early)), 6),
            "intrinsic_reward_mean": round(float(np.mean([r["intrinsic_reward"] for r in rows])), 6),
            "intrinsic_curve": {"updates": [int(r.get("updates", 0)) for r in rows],
                                "intrinsic_reward": [round(float(r["intrinsic_reward"]), 6) for r in rows]}}


def stage_cost(run_dir: RunDirectory) -> dict[str, Any]:
    """One stage of an agent-count curriculum: its agent count, episodes, training seconds and how it ended."""
    rows = list(run_dir.rows("episode"))
    return {"agents": run_dir.config().env.spread.num_agents, "episodes": len(rows),
            "wall_s": float(rows[-1].get("elapsed_s", 0.0)) if rows else 0.0, "ended": run_dir.summary().get("ended")}


def sampling_over_training(progress: list[dict[str, Any]], upto: int | None = None) -> dict[str, Any]:
    """The sampling distribution over training from a run's progress rows (up to episode `upto`): per row, the mean
    over the agents that do not sample uniformly of the ESS fraction and of the reward-bearing rows' share in the
    sampled minibatch (expected under P) and in the buffer (cmcl.replay.diagnostics.sampling_diagnostics), λ and, for
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

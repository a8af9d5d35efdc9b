"""The end of a training run, the same for both runners: the `done` line, then (unless --no-eval) the learning
curve, the held-out evaluation beside the random policy, the miss anatomy and a GIF of one episode."""

from __future__ import annotations

from typing import Any

import numpy as np

from cmcl.config import Config
from cmcl.run.flags import no_update_line
from cmcl.run.rundir import RunDirectory


def done_line(summary: dict[str, Any], stop_coverage: float) -> str:
    """"done: E episodes, S env steps, U updates in Ts" from a run's summary (episodes, env_steps, updates, elapsed_s,
    segment_s, ended), with " (Ns of them this time)" on a resumed run and why it ended early."""
    segment = summary.get("segment_s", summary["elapsed_s"])
    resumed = f" ({segment:.0f}s of them this time)" if summary["elapsed_s"] - segment >= 0.5 else ""
    why = {"solved": f" (coverage target {stop_coverage} reached)",
           "plateau": " (learning stopped progressing: run.stop_progress)"}.get(summary.get("ended"), "")
    return (f"done: {summary['episodes']} episodes, {summary['env_steps']} env steps, {summary['updates']} updates "
            f"in {summary['elapsed_s']:.0f}s{resumed}{why}")


EVAL_SECONDS = 60.0  # s: the most the end-of-run evaluation of both policies takes (each gets half; `eval_bound_s`)
EVAL_CHUNK = 10  # worlds an env.factory evaluation steps at once, between which it reports and checks its bound


def eval_bound_s(config: Config) -> float:
    """Seconds the end-of-run evaluation may take: EVAL_SECONDS, or half of run.max_seconds when a wall-clock budget
    is set and that is less (at least 10 s)."""
    budget = config.run.max_seconds
    return min(EVAL_SECONDS, max(10.0, budget / 2)) if budget > 0 else EVAL_SECONDS


def bounded_evaluation(config: Config, policy: Any, episodes: int, seconds: float, label: str,
                       progress: Any = print) -> dict[str, Any]:
    """`cmcl.run.evaluate.evaluate_policy` of `policy` (None: random) on up to `episodes` held-out worlds. The built-in
    tasks' batched twins play them all at once (well under a second); an env.factory environment, stepped one world
    after another at its own cost, plays them EVAL_CHUNK worlds at a time (seeds 0, 1, ...), says its progress after
    each chunk, and starts no chunk once `seconds` have passed: the result counts the episodes played ("episodes")."""
    import time

    from cmcl.run.evaluate import evaluate_policy

    if not config.env.factory:
        return evaluate_policy(config, policy, episodes)
    started, parts, done = time.monotonic(), [], 0
    while done < episodes and (not parts or time.monotonic() - started < seconds):
        parts.append(evaluate_policy(config, policy, min(EVAL_CHUNK, episodes - done), seed=len(parts)))
        done += parts[-1]["episodes"]
        progress(f"evaluation ({label}): {done} of {episodes} episodes, {time.monotonic() - started:.0f} s")
    return pooled(parts)


def pooled(parts: list[dict[str, Any]]) -> dict[str, Any]:
    """Evaluation results of disjoint world sets as one: means weighted by their episodes, standard deviations from
    the pooled second moments, team returns likewise; "episodes" their sum."""
    weights = np.array([part["episodes"] for part in parts], np.float64)
    share = weights / weights.sum()
    out: dict[str, Any] = {"episodes": int(weights.sum()), "policy": parts[0]["policy"]}
    for key in parts[0]:
        if key.endswith("_std") or not isinstance(parts[0][key], float):
            continue
        means = np.array([part[key] for part in parts])
        out[key] = float(share @ means)
        if f"{key}_std" in parts[0]:
            second = share @ (np.array([part[f"{key}_std"] for part in parts]) ** 2 + means ** 2)
            out[f"{key}_std"] = float(np.sqrt(max(0.0, second - out[key] ** 2)))
    out["reward"] = {team: float(share @ np.array([part["reward"][team] for part in parts]))
                     for team in parts[0]["reward"]}
    return out


def report_trained(config: Config, run_dir: RunDirectory, episodes: int = 200) -> None:
    """Held-out evaluation of the run's newest verified policy (no exploration noise, worlds never trained on)
    beside the random policy's, within `eval_bound_s` (a line when it starts, naming --no-eval; its progress on an
    env.factory environment), a GIF of one episode and the learning curve, all in the run directory; printed. A run
    without a learner update says so first (`no_update_line`)."""
    from cmcl.run.evaluate import beside_random, gif_line, load_policy, saturation_line
    from cmcl.run.plots import curve_line
    from cmcl.run.stalls import MissAnatomy

    untrained = no_update_line(config, run_dir.summary())
    if untrained:
        print(untrained)

    if any(True for _ in run_dir.rows("episode")):
        window = min(config.run.smoothing_window, max(1, config.run.episodes // 10))
        print(curve_line([run_dir.path], run_dir.path / "learning_curve.png", window=window))
    checkpoint = run_dir.newest_policy()
    if checkpoint is None:
        print(f"no policy checkpoint in {run_dir.path}: nothing to evaluate")
        return
    policy = load_policy(config, checkpoint)
    bound = eval_bound_s(config)
    print(f"evaluation: the trained policy, then the random one, on up to {episodes} held-out worlds each, within "
          f"about {bound:.0f} s (--no-eval skips it)")
    trained = bounded_evaluation(config, policy, episodes, bound / 2, "trained")
    random = bounded_evaluation(config, None, trained["episodes"], bound / 2, "random")
    print(beside_random(trained, random, min(trained["episodes"], random["episodes"])))
    saturated = saturation_line(trained)
    if saturated:
        print(saturated)
    if "misses" in trained:
        print("\n".join(MissAnatomy(**trained["misses"]).lines()))
    print(gif_line(config, policy, run_dir.path / "trained.gif"))

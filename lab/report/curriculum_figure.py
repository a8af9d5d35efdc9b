"""The curriculum grids' figure: what each arm learned and how it sampled, over training, from the runs' summaries.

Three panels per grid (x: episodes), each a mean over an arm's seeds with a bootstrap 95% band:
(a) the training coverage (final-step landmark cover rate, 100-episode windows); on predator-prey the predators' win
    (share of episodes with a capture);
(b) the ESS of the sampling distribution as a fraction of the buffer (1 = uniform);
(c) the share of reward-bearing rows in the sampled minibatches divided by their share in the buffer (log axis;
    1 = as in the buffer, below 1 = the sampler avoids them).
A dotted line marks the mean episode at which λ reaches 0.5, after which KP excludes no row (ALGORITHM.md A10).
Drawn by `python -m lab report` into <grid results>/figures/curriculum_sampling.png.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from experiments.labels import ARM_COLOUR, ARM_LABEL, ARM_ORDER
from lab.report.figures import band, save
from lab.report.stats import bootstrap_band

SAMPLING_STEP = 200  # episodes between the common x points the runs' progress rows are interpolated onto
LEAST_BUFFER_SHARE = 0.005  # below it the sampled / buffer ratio of a progress row is not drawn (0 / 0 early on)
LEAST_RATIO = 1e-3  # ratios below it (no reward row sampled at all) are drawn at it, the log axis's floor


def sampling_band(ax: Any, x: np.ndarray, rows: list[np.ndarray], colour: str) -> None:
    """Mean over runs of rows (float64[x.size] each, NaN where undefined) with its bootstrap 95% band where two or
    more runs have a value (within the runs' values: an ESS band stays in [0, 1], a ratio's above 0)."""
    mean, lo, hi = bootstrap_band(np.array(rows))
    ax.plot(x, mean, color=colour)
    if np.isfinite(lo).any():
        ax.fill_between(x, lo, hi, color=colour, alpha=0.2, linewidth=0)


def on_grid(run: dict[str, Any], x: np.ndarray, key: str) -> np.ndarray:
    """The run's progress-row measure `key` interpolated onto episodes x (NaN outside the rows' span)."""
    curve = run["sampling_curve"]
    return np.interp(x, curve["episode"], curve[key], left=np.nan, right=np.nan)


def reward_row_ratio(run: dict[str, Any], x: np.ndarray) -> np.ndarray:
    """Sampled share / buffer share of reward-bearing rows on episodes x; NaN where the buffer share is tiny."""
    buffer = on_grid(run, x, "reward_rows_buffer")
    ratio = on_grid(run, x, "reward_rows_sampled") / np.maximum(buffer, LEAST_BUFFER_SHARE)
    return np.where(buffer >= LEAST_BUFFER_SHARE, np.maximum(ratio, LEAST_RATIO), np.nan)


def episode_lambda_reaches(runs: list[dict[str, Any]], level: float) -> float | None:
    """Mean over the ACL and CMCL-family runs whose λ got there of the episode at which λ first reaches `level`
    (interpolated between progress rows; λ grows monotonically); None if no such run."""
    reached = []
    for r in runs:
        curve = r.get("sampling_curve")
        if r.get("arm", "").startswith(("acl", "cmcl")) and curve and max(curve["lambda"]) >= level:
            reached.append(np.interp(level, curve["lambda"], curve["episode"]))
    return float(np.mean(reached)) if reached else None


def lambda_half_lines(runs: list[dict[str, Any]], arms: tuple[str, ...], budget: int) -> dict[str | None, float]:
    """Where the figure marks λ reaching 0.5: {None: episode} when the arms' λ schedules agree (within a tenth of the
    budget), else {arm: episode} for each arm whose λ got there (the λ-schedule grid)."""
    per_arm = {arm: episode_lambda_reaches([r for r in runs if r.get("arm") == arm], 0.5) for arm in arms}
    reached = {arm: e for arm, e in per_arm.items() if e is not None}
    if reached and max(reached.values()) - min(reached.values()) > budget / 10:
        return reached
    everyone = episode_lambda_reaches([r for r in runs if r.get("arm") in arms], 0.5)
    return {} if everyone is None else {None: everyone}


def curriculum_figure(runs: list[dict[str, Any]], task: str, path: Path,
                      arms: tuple[str, ...] = ARM_ORDER) -> Path:
    """Draw the three panels for the finished runs of one curriculum grid (summaries with `arm`,
    `curves.coverage` (predator-prey: `curves.predator_win`) and `sampling_curve`) into `path`, one band per arm of
    `arms` in that order; returns it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    budget = max(r["budget"] for r in runs)
    predator_prey = runs[0].get("task") == "tag"
    curve = "predator_win" if predator_prey else "coverage"
    x = np.arange(SAMPLING_STEP, budget + 1, SAMPLING_STEP, dtype=np.float64)
    fig, axes = plt.subplots(1, 3, figsize=(17, 4.9))
    for arm in arms:
        rs = [r for r in runs if r.get("arm") == arm and r.get("sampling_curve")]
        if not rs:
            continue
        band(axes[0], [r["curves"][curve] for r in rs], ARM_COLOUR[arm], ARM_LABEL[arm], rate=True)
        sampling_band(axes[1], x, [on_grid(r, x, "ess") for r in rs], ARM_COLOUR[arm])
        sampling_band(axes[2], x, [reward_row_ratio(r, x) for r in rs], ARM_COLOUR[arm])
    no_exclusion = lambda_half_lines(runs, arms, budget)
    for ax in axes:
        for arm, episode in no_exclusion.items():
            ax.axvline(episode, color="grey" if arm is None else ARM_COLOUR[arm], linestyle=":", linewidth=1)
        ax.set_xlabel("episode")
    if predator_prey:
        axes[0].set(ylabel="episodes with a capture (100-episode windows)", ylim=(0, 1.02),
                    title="(a) training predator win")
    else:
        axes[0].set(ylabel="final-step landmark cover rate (100-episode windows)", ylim=(0, 1.02),
                    title="(a) training coverage")
    axes[0].legend(loc="lower right", fontsize=7)
    axes[1].set(ylabel="ESS / buffer rows (1 = uniform)", ylim=(0, 1.02),
                title="(b) effective sample size of the sampling")
    axes[2].set_yscale("log")
    axes[2].set_ylim(LEAST_RATIO * 0.8, 10)
    axes[2].axhline(1.0, color="black", linewidth=0.8)
    axes[2].set(ylabel="reward-bearing rows: share sampled / share in buffer",
                title="(c) reward rows sampled against the buffer (1 = as in it)")
    fig.suptitle(f"{task}: mean and 95% band over seeds, {budget:,} episodes per run, inline;\ndotted: λ reaches 0.5 "
                 "(KP excludes no row after it" + ("" if None in no_exclusion else "; in each arm's colour") + ")")
    return save(fig, path)

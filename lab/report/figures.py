"""The figures of the paper's grids in the paper's form, each labelled with the budget it rests on: Figs. 8, 9, 12
and 13, success and episodes-to-solve plots, and the ablations' coverage curves; PNGs into <results>/figures/
(`python -m lab figures`, also drawn by `python -m lab report`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from experiments.labels import COLOUR, LABEL, ORDER
from experiments.measures import WINDOW
from lab.report.stats import bootstrap_band, mean_ci


def band(ax: Any, curves: list[list[float]], colour: str, label: str, rate: bool = False) -> None:
    """Mean curve over seeds with its 95% band: for a rate (coverage, success, win: rate=True) a bootstrap band, which
    stays in [0, 1], else a t band; x in episodes (window ends)."""
    n = min(len(c) for c in curves)
    y = np.array([c[:n] for c in curves], dtype=np.float64)
    x = (np.arange(n) + 1) * WINDOW
    m = y.mean(0)
    ax.plot(x, m, color=colour, label=f"{label} ({len(curves)} seeds)")
    if len(curves) > 1:
        if rate:
            _, lo, hi = bootstrap_band(y)
        else:
            h = stats.t.ppf(0.975, len(curves) - 1) * y.std(0, ddof=1) / np.sqrt(len(curves))
            lo, hi = m - h, m + h
        ax.fill_between(x, lo, hi, color=colour, alpha=0.2, linewidth=0)


def budget(runs: list[dict[str, Any]]) -> str:
    return f"{max(r['budget'] for r in runs):,} episodes per run, inline"


def figures(runs: list[dict[str, Any]], out: Path) -> list[Path]:
    """The paper's figures of whatever has finished; returns the PNGs written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    written = []
    spread = [r for r in runs if r.get("grid", "spread") == "spread"]
    by_alg = {a: [r for r in spread if r["algorithm"] == a] for a in ORDER}
    if spread:
        fig, axes = plt.subplots(1, 2, figsize=(11, 4))  # Fig. 8: average reward and landmark cover rate
        for a, rs in by_alg.items():
            if rs:
                band(axes[0], [r["curves"]["reward_agent"] for r in rs], COLOUR[a], LABEL[a])
                band(axes[1], [r["curves"]["coverage"] for r in rs], COLOUR[a], LABEL[a], rate=True)
        axes[0].set(xlabel="episode", ylabel="team return per episode (100-episode windows)",
                    title="(a) average reward")
        axes[1].set(xlabel="episode", ylabel="final-step landmark cover rate", title="(b) landmark cover rate",
                    ylim=(0, 1.02))
        axes[1].legend(loc="lower right")
        fig.suptitle(f"Sparse cooperative navigation N=4 (Fig. 8 form); mean and 95% CI over seeds; {budget(spread)}")
        written.append(save(fig, out / "fig8_spread_curves.png"))

        fig, ax = plt.subplots(figsize=(6, 4))  # Fig. 9: mean reward bars
        present = [a for a in ORDER if by_alg[a]]
        means = [mean_ci([r["mean_reward"] for r in by_alg[a]]) for a in present]
        ax.bar([LABEL[a] for a in present], [m for m, _ in means], yerr=[0 if np.isnan(h) else h for _, h in means],
               color=[COLOUR[a] for a in present], capsize=6)
        for i, a in enumerate(present):
            ax.scatter([i] * len(by_alg[a]), [r["mean_reward"] for r in by_alg[a]], color="black", s=10, zorder=3)
        ax.set(ylabel="total reward / episodes (team, per episode)",
               title=f"Mean reward (Fig. 9 form), 95% CI, dots = seeds\n{budget(spread)}")
        written.append(save(fig, out / "fig9_spread_mean_reward.png"))

        fig, ax = plt.subplots(figsize=(6, 4))
        for a, rs in by_alg.items():
            if rs:
                band(ax, [r["curves"]["success"] for r in rs], COLOUR[a], LABEL[a], rate=True)
        ax.set(xlabel="episode", ylabel="success rate (all landmarks, distinct agents)", ylim=(0, 1.02),
               title=f"Success rate, mean and 95% CI over seeds\n{budget(spread)}")
        ax.legend(loc="upper left")
        written.append(save(fig, out / "spread_success_curves.png"))

        fig, ax = plt.subplots(figsize=(6, 4))
        for i, a in enumerate(present):
            for j, key in enumerate(("episodes_to_50", "episodes_to_90")):
                ys = [r[key] for r in by_alg[a]]
                got = [y for y in ys if y is not None]
                ax.scatter([i + (j - 0.5) * 0.3] * len(got), got, color=COLOUR[a], marker="o" if j else "^", s=18)
                if len(got) < len(ys):
                    ax.annotate(f"{len(ys) - len(got)} never", (i + (j - 0.5) * 0.3, 20_000), ha="center",
                                fontsize=7)
        ax.set_xticks(range(len(present)), [LABEL[a] for a in present])
        ax.set(ylabel="episodes until the 100-episode MA reaches it", ylim=(0, 21_000),
               title=f"Episodes to a cover rate of 0.5 (triangles) and 0.9 (dots)\n{budget(spread)}")
        written.append(save(fig, out / "spread_episodes_to_solve.png"))
    ablations = [r for r in runs if r.get("grid") == "ablations"]
    if ablations and by_alg["cmcl"]:
        written.append(ablation_figure(ablations, by_alg["cmcl"], out, plt))
    tag = [r for r in runs if r["task"] == "tag" and r["prey_algorithm"] == "maddpg"]
    if tag:
        fig, ax = plt.subplots(figsize=(6, 4))  # Fig. 12: predator reward against MADDPG prey
        for a in ORDER:
            rs = [r for r in tag if r["algorithm"] == a]
            if rs:
                band(ax, [r["curves"]["reward_predator"] for r in rs], COLOUR[a], LABEL[a])
        ax.set(xlabel="episode", ylabel="predator team return per episode",
               title=f"Predator-prey: predators vs MADDPG prey (Fig. 12 form)\n{budget(tag)}")
        ax.legend()
        written.append(save(fig, out / "fig12_tag_predator_reward.png"))
    duel = [r for r in runs if r["task"] == "tag" and r["algorithm"] == "cmcl" and r["prey_algorithm"] in
            ("acl", "per")]
    if duel:
        fig, ax = plt.subplots(figsize=(6, 4))  # Fig. 13: CMCL predators' win rate against ACL / PER prey
        for prey in ("acl", "per"):
            rs = [r for r in duel if r["prey_algorithm"] == prey]
            if rs:
                band(ax, [r["curves"]["predator_win"] for r in rs], COLOUR[prey],
                     f"CMCL predators vs {LABEL[prey]} prey", rate=True)
        ax.axhline(0.85, color="grey", linestyle=":", label="paper: > 0.85 vs PER-MADDPG")
        ax.set(xlabel="episode", ylabel="predator win rate (>= 1 capture per round)", ylim=(0, 1.02),
               title=f"Win rate of CMCL predators (Fig. 13 form)\n{budget(duel)}")
        ax.legend(loc="lower right")
        written.append(save(fig, out / "fig13_cmcl_win_rate.png"))
    return written


def ablation_figure(ablations: list[dict[str, Any]], reference: list[dict[str, Any]], out: Path, plt: Any) -> Path:
    """Coverage curves of the CMCL variants against the unchanged CMCL runs: (a) the full-budget variants (means
    over seeds; the reference with its 95% band), (b) the shorter ones (the paper's schedule) against the
    reference's first episodes, both with bands."""
    full = max(r["budget"] for r in reference)
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in ablations:
        groups.setdefault(r["ablation"], []).append(r)
    budgets = [full] + sorted({rs[0]["budget"] for rs in groups.values() if rs[0]["budget"] < full})[-1:]
    fig, axes = plt.subplots(1, len(budgets), figsize=(6 * len(budgets), 4.2), squeeze=False)
    for ax, budget_of in zip(axes[0], budgets, strict=True):
        n = budget_of // WINDOW
        band(ax, [r["curves"]["coverage"][:n] for r in reference], "black", "reference", rate=True)
        colours = iter(plt.get_cmap("tab10").colors)
        for name, rs in groups.items():
            if rs[0]["budget"] != budget_of:
                continue
            curves = [r["curves"]["coverage"] for r in rs]
            if budget_of == full:
                m = np.array([c[: min(map(len, curves))] for c in curves]).mean(0)
                ax.plot((np.arange(m.size) + 1) * WINDOW, m, color=next(colours), linewidth=1,
                        label=f"{name} ({len(rs)} seeds)")
            else:
                band(ax, curves, next(colours), name, rate=True)
        ax.set(xlabel="episode", ylabel="final-step landmark cover rate (100-episode windows)", ylim=(0, 1.02),
               title=f"({'a' if budget_of == full else 'b'}) first {budget_of:,} episodes")
        ax.legend(loc="upper left", fontsize=7)
    fig.suptitle("CMCL ablations on sparse navigation N=4, one setting changed at a time; inline")
    return save(fig, out / "ablations_coverage.png")


def save(fig: Any, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path

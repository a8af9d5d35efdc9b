"""The markdown tables of the paper's grids (spread, tag, winrate, ablations) and of the time-to-solve grids
(schedule, algorithms): one row per algorithm or cell, its mean and 95% interval over seeds (lab.report.stats),
and the tests of CMCL against each baseline."""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy import stats

from experiments.labels import LABEL, ORDER
from lab.report.stats import fmt, logrank_p, median_text, paired, spread, welch

BASELINES = ("maddpg", "per", "acl")  # what CMCL is tested against in the paper's grids
# the measures of CMCL − each baseline: navigation (tests_table), predator-prey against MADDPG prey (tag_tests_table)
SPREAD_TESTS = [("mean reward", "mean_reward", 1), ("area under coverage", "auc_coverage", 3),
                ("held-out success", "held_out_success", 3)]
TAG_TESTS = [("mean predator reward", "mean_reward_predator", 1), ("win vs trained prey", "win_vs_trained_prey", 3),
             ("win vs random prey", "win_vs_random_prey", 3)]
FIG13_WIN = 0.85  # the paper's Fig. 13: CMCL predators win above this against PER-MADDPG prey

SPREAD_COLUMNS = [("held-out coverage", "held_out_coverage", 3), ("held-out success", "held_out_success", 3),
                  ("episodes to MA 0.5", "episodes_to_50", 0), ("episodes to MA 0.9", "episodes_to_90", 0),
                  ("area under coverage", "auc_coverage", 3), ("final MA success", "final_ma_success", 3),
                  ("mean reward per episode", "mean_reward", 1), ("seconds to MA 0.9", "seconds_to_90", 0),
                  ("wall s", "wall_s", 0)]


def spread_table(runs: list[dict[str, Any]]) -> str:
    """One row per algorithm: mean ± 95% CI over its seeds of each measure."""
    lines = ["| algorithm | seeds | " + " | ".join(c[0] for c in SPREAD_COLUMNS) + " |",
             "| --- " * (len(SPREAD_COLUMNS) + 2) + "|"]
    for algorithm in ORDER:
        rs = [r for r in runs if r["algorithm"] == algorithm]
        if rs:
            cells = [fmt([r.get(key) for r in rs], d, key) for _, key, d in SPREAD_COLUMNS]
            lines.append(f"| {LABEL[algorithm]} | {len(rs)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def seeds_table(runs: list[dict[str, Any]]) -> str:
    """Per run: held-out coverage / success and episodes to MA 0.9, one row per algorithm, one column per seed
    (which runs meet the target of coverage >= 0.9 and success >= 0.8)."""
    seeds = sorted({r["seed"] for r in runs})
    lines = ["| algorithm | " + " | ".join(f"seed {s}" for s in seeds) + " | runs meeting coverage ≥ 0.9 and "
             "success ≥ 0.8 |", "| --- " * (len(seeds) + 2) + "|"]
    for algorithm in ORDER:
        rs = {r["seed"]: r for r in runs if r["algorithm"] == algorithm}
        if not rs:
            continue
        cells = [(f"{rs[s]['held_out_coverage']:.3f} / {rs[s]['held_out_success']:.2f} / "
                  f"{rs[s]['episodes_to_90'] or 'never'}") if s in rs else "" for s in seeds]
        met = sum(r["held_out_coverage"] >= 0.9 and r["held_out_success"] >= 0.8 for r in rs.values())
        lines.append(f"| {LABEL[algorithm]} | " + " | ".join(cells) + f" | {met} of {len(rs)} |")
    return "\n".join(lines)


def tests_table(runs: list[dict[str, Any]]) -> str:
    """CMCL minus each baseline, per measure, by Welch's t-test; episodes to MA 0.9 (censored) by a log-rank test
    over every run, the ones that never got there included. p-values as computed (9 tests: see the text for the
    multiplicity)."""
    keys = SPREAD_TESTS
    cmcl = [r for r in runs if r["algorithm"] == "cmcl"]
    lines = ["| CMCL minus | " + " | ".join(k[0] for k in keys) + " | episodes to MA 0.9 (KM medians, log-rank) |",
             "| --- " * (len(keys) + 2) + "|"]
    for base in BASELINES:
        rs = [r for r in runs if r["algorithm"] == base]
        if rs and cmcl:
            cells = [welch([r[k] for r in cmcl], [r[k] for r in rs], d) for _, k, d in keys]
            budget = cmcl[0]["budget"]
            a, b = [r["episodes_to_90"] for r in cmcl], [r["episodes_to_90"] for r in rs]
            cells.append(f"{median_text(a, missing='—')} vs {median_text(b, missing='—')}, "
                         f"p = {logrank_p(a, b, budget):.3f}")
            lines.append(f"| {LABEL[base]} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def ablation_table(ablations: list[dict[str, Any]], reference: list[dict[str, Any]]) -> str:
    """One row per CMCL variant and per reference (the unchanged CMCL runs, and those runs read up to a smaller
    budget that a variant ran): mean ± 95% CI of the main measures, and the variant minus the reference of the
    same seeds and the same budget in area under coverage and held-out success (paired t)."""
    keys = [("held-out coverage", "held_out_coverage", 3), ("held-out success", "held_out_success", 3),
            ("episodes to MA 0.9", "episodes_to_90", 0), ("area under coverage", "auc_coverage", 3),
            ("mean reward per episode", "mean_reward", 1), ("wall s", "wall_s", 0)]
    lines = ["| CMCL variant | episodes | seeds | " + " | ".join(k[0] for k in keys)
             + " | area: variant − reference, same seeds | held-out success: variant − reference, same seeds |",
             "| --- " * (len(keys) + 5) + "|"]
    references: dict[int, list[dict[str, Any]]] = {}
    for r in reference:
        references.setdefault(r["budget"], []).append(r)
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in ablations:
        groups.setdefault(r["ablation"], []).append(r)
    rows: list[tuple[str, list[dict[str, Any]], list[dict[str, Any]] | None]] = []
    full = max(references, default=0)
    for budget in sorted(references, reverse=True):
        label = "reference (η 0.5, K 5, max, default stride, IS off)" if budget == full else \
            f"reference, its first {budget:,} episodes"
        rows.append((label, references[budget], None))
        rows += [(name, rs, references[budget]) for name, rs in groups.items() if rs[0]["budget"] == budget]
    rows += [(name, rs, []) for name, rs in groups.items() if rs[0]["budget"] not in references]
    for name, rs, ref in rows:
        diffs = ["", ""] if ref is None else [
            paired({r["seed"]: r[k] for r in rs}, {r["seed"]: r[k] for r in ref}, 3)
            for k in ("auc_coverage", "held_out_success")]
        seeds = ",".join(str(s) for s in sorted(r["seed"] for r in rs))
        lines.append(f"| {name} | {rs[0]['budget']:,} | {seeds} | "
                     + " | ".join(fmt([r.get(k) for r in rs], d, k) for _, k, d in keys)
                     + f" | {diffs[0]} | {diffs[1]} |")
    return "\n".join(lines)


def tag_table(runs: list[dict[str, Any]]) -> str:
    """Predator-prey rows: predators' algorithm vs prey's; reward, win rates."""
    lines = ["| predators | prey | seeds | mean predator reward per episode | final MA win | win vs trained prey "
             "(held-out) | win vs random prey | wall s |", "| --- " * 8 + "|"]
    for (pred, prey) in sorted({(r["algorithm"], r["prey_algorithm"]) for r in runs}):
        rs = [r for r in runs if (r["algorithm"], r["prey_algorithm"]) == (pred, prey)]
        lines.append(f"| {LABEL[pred]} | {LABEL[prey]} | {len(rs)} | " + " | ".join(
            fmt([r[k] for r in rs], d, k) for k, d in (("mean_reward_predator", 1), ("final_ma_predator_win", 3),
                                                   ("win_vs_trained_prey", 3), ("win_vs_random_prey", 3),
                                                   ("wall_s", 0))) + " |")
    return "\n".join(lines)


def predators_vs_maddpg_prey(runs: list[dict[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    """algorithm -> the runs of its predators against MADDPG prey (the tag grid's cells of the paper's Fig. 12)."""
    return {a: [r for r in runs if r["algorithm"] == a and r["prey_algorithm"] == "maddpg"] for a in ORDER}


def against_threshold(wins: list[float]) -> tuple[float, float]:
    """(mean − FIG13_WIN, two-sided p of a one-sample t-test of the mean against FIG13_WIN); p nan for one run."""
    p = float(stats.ttest_1samp(wins, FIG13_WIN).pvalue) if len(wins) > 1 else float("nan")
    return float(np.mean(wins) - FIG13_WIN), p


def tag_tests_table(runs: list[dict[str, Any]]) -> str:
    """The tests behind the predator-prey verdicts. Fig. 12: CMCL predators minus each baseline's predators (all
    against MADDPG prey), Welch. Fig. 13: CMCL predators' held-out win rate against ACL and PER-MADDPG prey, with a
    one-sample t-test of the mean against the paper's 0.85."""
    vs_maddpg = predators_vs_maddpg_prey(runs)
    lines = ["| CMCL predators minus (prey: MADDPG) | " + " | ".join(k[0] for k in TAG_TESTS) + " |",
             "| --- " * (len(TAG_TESTS) + 1) + "|"]
    for base in BASELINES:
        if vs_maddpg["cmcl"] and vs_maddpg[base]:
            lines.append(f"| {LABEL[base]} predators | " + " | ".join(
                welch([r[k] for r in vs_maddpg["cmcl"]], [r[k] for r in vs_maddpg[base]], d) for _, k, d in TAG_TESTS)
                + " |")
    lines += ["", "| CMCL predators against | seeds | held-out win rate | t-test of the mean against 0.85 |",
              "| --- | --- | --- | --- |"]
    for prey in ("acl", "per"):
        wins = [r["win_vs_trained_prey"] for r in runs if r["algorithm"] == "cmcl" and r["prey_algorithm"] == prey]
        if wins:
            above, p = against_threshold(wins)
            test = f"mean − 0.85 = {above:+.3f}, p = {p:.3f}" if len(wins) > 1 else "n/a"
            lines.append(f"| {LABEL[prey]} prey | {len(wins)} | {fmt(wins, 3, 'win_vs_trained_prey')} | {test} |")
    return "\n".join(lines)


def solve_cells(runs: list[dict[str, Any]]) -> str:
    """The cells of one time-to-solve row from its seeds on: 'mean (min..max)' over the runs (sorted by seed)."""
    rs = sorted(runs, key=lambda r: r["seed"])
    return (f"{','.join(str(r['seed']) for r in rs)} | {spread([r['episodes_to_90'] for r in rs])} | "
            f"{spread([r['seconds_to_90'] for r in rs])} | {spread([r['episodes_to_50'] for r in rs])} | "
            f"{spread([r['held_out_coverage'] for r in rs], '{:.3f}')} | "
            + " | ".join(spread([r[f"held_out_{k}"] for r in rs], "{:.2f}") for k in ("success", "collisions",
                                                                                      "wall_hits")))


SOLVE_HEADER = ("seeds | episodes to MA 0.9 | seconds to MA 0.9 | episodes to MA 0.5 | held-out coverage | held-out "
                "success | collisions | wall hits |")  # the columns of solve_cells


def solve_groups(runs: list[dict[str, Any]], fields: tuple[str, ...]) -> dict[tuple, list[dict[str, Any]]]:
    """The navigation runs of a time-to-solve grid grouped by `fields` (mode inline when a run names none)."""
    groups: dict[tuple, list[dict[str, Any]]] = {}
    for r in (r for r in runs if r.get("task", "spread") == "spread"):
        groups.setdefault(tuple(r.get(f, "inline") if f == "mode" else r[f] for f in fields), []).append(r)
    return groups


def solve_tag_table(runs: list[dict[str, Any]]) -> str:
    """The predator-prey runs of the older time-to-solve log: one row per predators' algorithm, 'mean (min..max)'."""
    tag = sorted((r for r in runs if r.get("task") == "tag"), key=lambda r: (r["algorithm"], r["seed"]))
    lines = ["| predators | seeds | win vs trained MADDPG prey | win vs random prey | random vs random | "
             "training MA win at the end | seconds |", "| --- " * 7 + "|"]
    for algorithm in sorted({r["algorithm"] for r in tag}):
        rs = [r for r in tag if r["algorithm"] == algorithm]
        lines.append(f"| {algorithm} | {','.join(str(r['seed']) for r in rs)} | "
                     + " | ".join(spread([r.get(k) for r in rs], "{:.3f}") for k in
                                  ("win_vs_trained_prey", "win_vs_random_prey", "random_vs_random",
                                   "final_ma_predator_win"))
                     + f" | {spread([r['wall_s'] for r in rs])} |")
    return "\n".join(lines)


def solve_table(runs: list[dict[str, Any]]) -> str:
    """The time-to-solve grids (schedule, algorithms): one row per (grid, mode, algorithm, update_every, batch),
    'mean (min..max)' over its seeds; then predator-prey rows of the older log, if any."""
    groups = solve_groups(runs, ("grid", "mode", "algorithm", "update_every", "batch_size"))
    lines = ["| grid | mode | algorithm | update_every | batch | " + SOLVE_HEADER, "| --- " * 13 + "|"]
    for key in sorted(groups):
        lines.append("| " + " | ".join(str(k) for k in key) + f" | {solve_cells(groups[key])} |")
    if any(r.get("task") == "tag" for r in runs):
        lines += ["", solve_tag_table(runs)]
    return "\n".join(lines)

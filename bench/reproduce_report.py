"""Tables and figures of the reproduction grid (bench/reproduce.py): mean ± 95% CI over seeds, Welch tests of CMCL
against each baseline, and the paper's figures in its form, each labelled with the budget it rests on.

    python bench/reproduce_report.py [--out bench/results/reproduce] [--update docs/RESULTS.md]

Reads <out>/summaries/*.json; writes <out>/figures/*.png (drawn by bench/reproduce_figures.py); prints the
markdown tables (and with --update, replaces the text between the `<!-- name:begin -->` /
`<!-- name:end -->` markers of that file).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

ROOT = Path(__file__).resolve().parents[1]
ORDER = ("maddpg", "per", "acl", "cmcl")
LABEL = {"maddpg": "MADDPG", "per": "PER-MADDPG", "acl": "ACL", "cmcl": "CMCL"}
COLOUR = {"maddpg": "tab:blue", "per": "tab:orange", "acl": "tab:green", "cmcl": "tab:red"}
WINDOW = 100


def load(out: Path) -> list[dict[str, Any]]:
    return [json.loads(p.read_text()) for p in sorted((out / "summaries").glob("*.json"))]


def mean_ci(values: list[float]) -> tuple[float, float]:
    """(mean, half-width of the two-sided 95% t interval); half-width nan for fewer than 2 values."""
    x = np.asarray(values, dtype=np.float64)
    if x.size < 2:
        return float(x.mean()) if x.size else float("nan"), float("nan")
    return float(x.mean()), float(stats.t.ppf(0.975, x.size - 1) * x.std(ddof=1) / np.sqrt(x.size))


def fmt(values: list[float | None], digits: int = 3) -> str:
    """'mean ± ci' over the values that exist, with 'k/n never' for missing (None) ones."""
    got = [v for v in values if v is not None]
    never = len(values) - len(got)
    if not got:
        return f"never ({never}/{len(values)})"
    m, h = mean_ci(got)
    text = f"{m:.{digits}f}" + ("" if np.isnan(h) else f" ± {h:.{digits}f}")
    return text + (f", {never}/{len(values)} never" if never else "")


def welch(a: list[float], b: list[float], digits: int = 3) -> str:
    """'Δ = mean(a) − mean(b) [95% CI], p' by Welch's unequal-variance t-test (two-sided)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.size < 2 or b.size < 2:
        return "n/a"
    va, vb = a.var(ddof=1) / a.size, b.var(ddof=1) / b.size
    diff, se = a.mean() - b.mean(), np.sqrt(va + vb)
    if se == 0:
        return f"{diff:+.{digits}f} (no spread)"
    dof = (va + vb) ** 2 / (va ** 2 / (a.size - 1) + vb ** 2 / (b.size - 1))
    half = stats.t.ppf(0.975, dof) * se
    p = stats.ttest_ind(a, b, equal_var=False).pvalue
    return f"{diff:+.{digits}f} [{diff - half:+.{digits}f}, {diff + half:+.{digits}f}], p = {p:.3f}"


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
            lines.append(f"| {LABEL[algorithm]} | {len(rs)} | " +
                         " | ".join(fmt([r.get(key) for r in rs], d) for _, key, d in SPREAD_COLUMNS) + " |")
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
    """CMCL minus each baseline, per measure, by Welch's t-test (runs that never reached 0.9 are left out of that
    measure and counted in the main table)."""
    keys = [("mean reward", "mean_reward", 1), ("area under coverage", "auc_coverage", 3),
            ("held-out success", "held_out_success", 3), ("episodes to MA 0.9", "episodes_to_90", 0)]
    cmcl = [r for r in runs if r["algorithm"] == "cmcl"]
    lines = ["| CMCL minus | " + " | ".join(k[0] for k in keys) + " |", "| --- " * (len(keys) + 1) + "|"]
    for base in ("maddpg", "per", "acl"):
        rs = [r for r in runs if r["algorithm"] == base]
        if rs and cmcl:
            cells = [welch([r[k] for r in cmcl if r.get(k) is not None], [r[k] for r in rs if r.get(k) is not None],
                           d) for _, k, d in keys]
            lines.append(f"| {LABEL[base]} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def paired(variant: dict[int, float], reference: dict[int, float], digits: int = 3) -> str:
    """'Δ = mean(variant − reference) [95% CI], p' over the seeds both have, by a paired two-sided t-test.

    variant, reference: {seed: value}. Inline runs are deterministic for a seed, so a variant and the reference of
    the same seed share their initial weights and worlds until the changed setting first acts."""
    seeds = sorted(set(variant) & set(reference))
    d = np.asarray([variant[s] - reference[s] for s in seeds], dtype=np.float64)
    if d.size < 2:
        return f"n/a ({d.size} paired seed{'s' if d.size != 1 else ''})"
    m, h = mean_ci(list(d))
    if np.all(d == d[0]):
        return f"{m:+.{digits}f} (no spread, n = {d.size})"
    p = stats.ttest_1samp(d, 0.0).pvalue
    return f"{m:+.{digits}f} [{m - h:+.{digits}f}, {m + h:+.{digits}f}], p = {p:.3f}, n = {d.size}"


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
                     + " | ".join(fmt([r.get(k) for r in rs], d) for _, k, d in keys) + f" | {diffs[0]} | {diffs[1]} |")
    return "\n".join(lines)


def tag_table(runs: list[dict[str, Any]]) -> str:
    """Predator-prey rows: predators' algorithm vs prey's; reward, win rates."""
    lines = ["| predators | prey | seeds | mean predator reward per episode | final MA win | win vs trained prey "
             "(held-out) | win vs random prey | wall s |", "| --- " * 8 + "|"]
    for (pred, prey) in sorted({(r["algorithm"], r["prey_algorithm"]) for r in runs}):
        rs = [r for r in runs if (r["algorithm"], r["prey_algorithm"]) == (pred, prey)]
        lines.append(f"| {LABEL[pred]} | {LABEL[prey]} | {len(rs)} | " + " | ".join(
            fmt([r[k] for r in rs], d) for k, d in (("mean_reward_predator", 1), ("final_ma_predator_win", 3),
                                                   ("win_vs_trained_prey", 3), ("win_vs_random_prey", 3),
                                                   ("wall_s", 0))) + " |")
    return "\n".join(lines)


def tag_tests_table(runs: list[dict[str, Any]]) -> str:
    """The tests behind the predator-prey verdicts. Fig. 12: CMCL predators minus each baseline's predators (all
    against MADDPG prey), Welch. Fig. 13: CMCL predators' held-out win rate against ACL and PER-MADDPG prey, with a
    one-sample t-test of the mean against the paper's 0.85."""
    vs_maddpg = {a: [r for r in runs if r["algorithm"] == a and r["prey_algorithm"] == "maddpg"] for a in ORDER}
    keys = [("mean predator reward", "mean_reward_predator", 1), ("win vs trained prey", "win_vs_trained_prey", 3),
            ("win vs random prey", "win_vs_random_prey", 3)]
    lines = ["| CMCL predators minus (prey: MADDPG) | " + " | ".join(k[0] for k in keys) + " |",
             "| --- " * (len(keys) + 1) + "|"]
    for base in ("maddpg", "per", "acl"):
        if vs_maddpg["cmcl"] and vs_maddpg[base]:
            lines.append(f"| {LABEL[base]} predators | " + " | ".join(
                welch([r[k] for r in vs_maddpg["cmcl"]], [r[k] for r in vs_maddpg[base]], d) for _, k, d in keys)
                + " |")
    lines += ["", "| CMCL predators against | seeds | held-out win rate | t-test of the mean against 0.85 |",
              "| --- | --- | --- | --- |"]
    for prey in ("acl", "per"):
        wins = [r["win_vs_trained_prey"] for r in runs if r["algorithm"] == "cmcl" and r["prey_algorithm"] == prey]
        if wins:
            test = (f"mean − 0.85 = {np.mean(wins) - 0.85:+.3f}, p = {stats.ttest_1samp(wins, 0.85).pvalue:.3f}"
                    if len(wins) > 1 else "n/a")
            lines.append(f"| {LABEL[prey]} prey | {len(wins)} | {fmt(wins, 3)} | {test} |")
    return "\n".join(lines)


def update(path: Path, blocks: dict[str, str]) -> None:
    """Replace each `<!-- name:begin -->...<!-- name:end -->` block of `path` by its new text."""
    text = path.read_text()
    for name, body in blocks.items():
        text = re.sub(rf"(<!-- {name}:begin -->\n).*?(<!-- {name}:end -->)",
                      lambda m, body=body: m[1] + body + "\n" + m[2], text, flags=re.S)
    path.write_text(text)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default=str(ROOT / "bench" / "results" / "reproduce"))
    parser.add_argument("--update", help="a markdown file whose marked blocks get the new tables")
    args = parser.parse_args()
    out = Path(args.out)
    runs = load(out)
    spread = [r for r in runs if r.get("grid", "spread") == "spread"]
    ablations = [r for r in runs if r.get("grid") == "ablations"]
    tag = [r for r in runs if r["task"] == "tag"]
    blocks = {"spread": spread_table(spread), "seeds": seeds_table(spread), "tests": tests_table(spread)}
    if ablations:
        blocks["ablations"] = ablation_table(ablations, [r for r in spread if r["algorithm"] == "cmcl"]
                                             + [r for r in runs if r.get("grid") == "ablation_reference"])
    if tag:
        blocks["tag"], blocks["tagtests"] = tag_table(tag), tag_tests_table(tag)
    for name, body in blocks.items():
        print(f"{name}:\n{body}\n")
    from reproduce_figures import figures  # a sibling script; it imports this module's constants

    for png in figures(runs, out / "figures"):
        print(f"figure: {png.relative_to(ROOT) if png.is_relative_to(ROOT) else png}")
    if args.update:
        update(Path(args.update), blocks)


if __name__ == "__main__":
    sys.exit(main())

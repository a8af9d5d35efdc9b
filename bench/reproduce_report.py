"""Tables and figures of the reproduction grid (bench/reproduce.py): mean and 95% interval over seeds, tests of CMCL
against each baseline, and the paper's figures in its form, each labelled with the budget it rests on.

Intervals: rates (coverage, success, win rates, area under coverage: all in [0, 1]) get a percentile bootstrap
interval of the mean over seeds (10,000 resamples, fixed seed), which stays inside [0, 1]; unbounded measures
(reward, seconds) a Student-t interval. Episodes to a moving-average threshold are censored at the budget (a run
that never gets there is not dropped): Kaplan-Meier median and the number of runs that got there, compared by a
log-rank test. The curriculum grid (issue 21) follows the protocol of docs/RESULTS.md: one primary comparison,
Holm's correction over all the others.

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


RATES = ("held_out_coverage", "held_out_success", "auc_coverage", "final_ma_coverage", "final_ma_success",
         "final_ma_predator_win", "win_vs_trained_prey", "win_vs_random_prey")  # measures in [0, 1]
TIMES = ("episodes_to_50", "episodes_to_90")  # censored at the run's budget when never reached (None)
BOOTSTRAP = 10_000


def bootstrap_ci(values: list[float], seed: int = 0) -> tuple[float, float, float]:
    """(mean, low, high): percentile bootstrap 95% interval of the mean (BOOTSTRAP resamples, fixed seed). It lies
    within [min, max] of the values, so a rate's interval stays in [0, 1]; with 5 seeds it is narrower than a t
    interval (it undercovers), which the pages that use it say."""
    x = np.asarray(values, dtype=np.float64)
    if x.size < 2:
        m = float(x.mean()) if x.size else float("nan")
        return m, float("nan"), float("nan")
    means = x[np.random.default_rng(seed).integers(0, x.size, (BOOTSTRAP, x.size))].mean(1)
    lo, hi = np.percentile(means, [2.5, 97.5])
    return float(x.mean()), float(lo), float(hi)


def km_median(times: list[float | None]) -> tuple[float | None, int]:
    """Kaplan-Meier median of a time to threshold, and how many runs reached it. times: one per run, None = not
    reached within the run's budget (right-censored there; every run of a table has the same budget, so every
    censoring comes after every event). Median None when the survival curve never falls to 0.5."""
    events = sorted(t for t in times if t is not None)
    at_risk, surv = len(times), 1.0
    for t in events:  # product-limit estimate: one event at a time, nobody censored before the budget
        surv *= 1 - 1 / at_risk
        at_risk -= 1
        if surv <= 0.5 + 1e-12:
            return float(t), len(events)
    return None, len(events)


def fmt_time(values: list[float | None], digits: int = 0) -> str:
    """'KM median M (k/n reached)' of a censored time to threshold."""
    med, k = km_median(values)
    head = "not reached" if med is None else f"KM median {med:.{digits}f}"
    return f"{head} ({k}/{len(values)} reached)"


def logrank_p(a: list[float | None], b: list[float | None], budget: float) -> float:
    """Two-sided log-rank p-value of two samples of times to threshold, censored at `budget` when None."""
    def data(x):
        return stats.CensoredData(uncensored=[t for t in x if t is not None],
                                  right=[budget] * sum(t is None for t in x))
    if all(t is None for t in a + b):
        return 1.0
    return float(stats.logrank(data(a), data(b)).pvalue)


def holm(pvalues: list[float]) -> list[float]:
    """Holm's step-down adjusted p-values (same order as given)."""
    p = np.asarray(pvalues, dtype=np.float64)
    order = np.argsort(p)
    adjusted = np.empty_like(p)
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (p.size - rank) * p[i]))
        adjusted[i] = running
    return adjusted.tolist()


def fmt(values: list[float | None], digits: int = 3, key: str = "") -> str:
    """One table cell over the runs: a censored time (key in TIMES) as its KM median and the runs that reached it;
    a rate (key in RATES) as 'mean [bootstrap 95% interval]'; anything else 'mean ± t half-width', with 'k/n never'
    for missing (None) values."""
    if key in TIMES:
        return fmt_time(values, digits)
    got = [v for v in values if v is not None]
    never = len(values) - len(got)
    if not got:
        return f"never ({never}/{len(values)})"
    if key in RATES:
        m, lo, hi = bootstrap_ci(got)
        text = f"{m:.{digits}f}" + ("" if np.isnan(lo) else f" [{lo:.{digits}f}, {hi:.{digits}f}]")
    else:
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
    keys = [("mean reward", "mean_reward", 1), ("area under coverage", "auc_coverage", 3),
            ("held-out success", "held_out_success", 3)]
    cmcl = [r for r in runs if r["algorithm"] == "cmcl"]
    lines = ["| CMCL minus | " + " | ".join(k[0] for k in keys) + " | episodes to MA 0.9 (KM medians, log-rank) |",
             "| --- " * (len(keys) + 2) + "|"]
    for base in ("maddpg", "per", "acl"):
        rs = [r for r in runs if r["algorithm"] == base]
        if rs and cmcl:
            cells = [welch([r[k] for r in cmcl], [r[k] for r in rs], d) for _, k, d in keys]
            budget = cmcl[0]["budget"]
            a, b = [r["episodes_to_90"] for r in cmcl], [r["episodes_to_90"] for r in rs]
            ma, mb = km_median(a)[0], km_median(b)[0]
            cells.append(f"{'—' if ma is None else f'{ma:.0f}'} vs {'—' if mb is None else f'{mb:.0f}'}, "
                         f"p = {logrank_p(a, b, budget):.3f}")
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
            lines.append(f"| {LABEL[prey]} prey | {len(wins)} | {fmt(wins, 3, 'win_vs_trained_prey')} | {test} |")
    return "\n".join(lines)


ARMS = ("maddpg", "per", "acl", "cmcl", "cmcl_permuted", "cmcl_anti")  # bench/reproduce.py CURRICULUM_ARMS
ARM_LABEL = {**LABEL, "cmcl_permuted": "CMCL, permuted control", "cmcl_anti": "CMCL, anti-curriculum"}
PRIMARY = ("cmcl", "maddpg", "auc_coverage")  # the pre-registered primary comparison (docs/RESULTS.md, protocol)
SECONDARY = [("cmcl", "per", "auc_coverage"), ("cmcl", "acl", "auc_coverage"), ("cmcl", "cmcl_permuted",
             "auc_coverage"), ("cmcl", "cmcl_anti", "auc_coverage"), ("acl", "maddpg", "auc_coverage"),
             ("per", "maddpg", "auc_coverage"), ("cmcl", "maddpg", "held_out_success"),
             ("cmcl", "maddpg", "episodes_to_90")]  # Holm-corrected together
STALL = (0.65, 0.85)  # final MA coverage of a run stuck at about three landmarks of four (issue 21)


def curriculum_table(runs: list[dict[str, Any]]) -> str:
    """The curriculum grid per arm: learning measures, stalls, and the sampling distribution over training."""
    keys = [("area under coverage", "auc_coverage", 3), ("held-out coverage", "held_out_coverage", 3),
            ("held-out success", "held_out_success", 3), ("episodes to MA 0.9", "episodes_to_90", 0)]
    lines = ["| arm | seeds | " + " | ".join(k[0] for k in keys) + " | stalled at ~3 of 4 | ESS over training | "
             "ESS, first quarter | reward-bearing rows, first quarter: sampled / buffer | wall s |",
             "| --- " * (len(keys) + 7) + "|"]
    for arm in ARMS:
        rs = sorted((r for r in runs if r.get("arm") == arm), key=lambda r: r["seed"])
        if not rs:
            continue
        stalled = sum(STALL[0] <= r["final_ma_coverage"] <= STALL[1] for r in rs)
        sampled, buffer = (np.mean([first_quarter(r, k) for r in rs]) for k in ("reward_rows_sampled",
                                                                                 "reward_rows_buffer"))
        lines.append(f"| {ARM_LABEL[arm]} | {len(rs)} | " + " | ".join(fmt([r.get(k) for r in rs], d, k)
                                                                   for _, k, d in keys)
                     + f" | {stalled}/{len(rs)} | {fmt([r['ess_mean'] for r in rs], 2, 'auc_coverage')} | "
                     f"{fmt([r['ess_first_quarter'] for r in rs], 2, 'auc_coverage')} | {sampled:.3f} / {buffer:.3f} | "
                     f"{fmt([r['wall_s'] for r in rs], 0)} |")
    return "\n".join(lines)


def first_quarter(run: dict[str, Any], key: str) -> float:
    """Mean of a run's sampling_curve column over its first quarter of episodes (λ < 0.5 at the default stride,
    where the curriculum can exclude rows)."""
    curve = run["sampling_curve"]
    values = [v for e, v in zip(curve["episode"], curve[key], strict=True) if e <= run["budget"] / 4]
    return float(np.mean(values)) if values else float("nan")


def difference(a: list[float], b: list[float], seed: int = 0) -> tuple[float, float, float, float]:
    """(mean(a) − mean(b), bootstrap 95% interval of it (each arm resampled on its own), Welch p)."""
    x, y = np.asarray(a, float), np.asarray(b, float)
    rng = np.random.default_rng(seed)
    boot = (x[rng.integers(0, x.size, (BOOTSTRAP, x.size))].mean(1)
            - y[rng.integers(0, y.size, (BOOTSTRAP, y.size))].mean(1))
    lo, hi = np.percentile(boot, [2.5, 97.5])
    p = float(stats.ttest_ind(x, y, equal_var=False).pvalue) if x.std() + y.std() > 0 else 1.0
    return float(x.mean() - y.mean()), float(lo), float(hi), p


def curriculum_tests(runs: list[dict[str, Any]]) -> str:
    """The protocol's tests: the primary comparison unadjusted, every other one Holm-corrected; times to MA 0.9 by
    KM medians and a log-rank test."""
    by_arm = {arm: [r for r in runs if r.get("arm") == arm] for arm in ARMS}
    rows, pvalues = [], []
    for a, b, key in [PRIMARY, *SECONDARY]:
        ra, rb = by_arm[a], by_arm[b]
        if len(ra) < 2 or len(rb) < 2:
            rows.append((a, b, key, "n/a (fewer than 2 runs)", None))
            pvalues.append(None)
            continue
        if key in TIMES:
            ta, tb = [r[key] for r in ra], [r[key] for r in rb]
            p = logrank_p(ta, tb, ra[0]["budget"])
            text = f"KM median {fmt_time(ta)} vs {fmt_time(tb)}"
        else:
            d, lo, hi, p = difference([r[key] for r in ra], [r[key] for r in rb])
            text = f"{d:+.3f} [{lo:+.3f}, {hi:+.3f}]"
        rows.append((a, b, key, text, p))
        pvalues.append(p)
    # Holm over the whole pre-registered family: a test without its runs yet counts as p = 1 (conservative)
    adjusted = [None, *holm([1.0 if p is None else p for p in pvalues[1:]])]
    lines = ["| comparison | measure | seeds | difference [bootstrap 95%] | p | p (Holm) |", "| --- " * 6 + "|"]
    for i, (a, b, key, text, p) in enumerate(rows):
        n = f"{len(by_arm[a])} vs {len(by_arm[b])}"
        adj = "primary" if i == 0 else "" if p is None else f"{adjusted[i]:.3f}"
        lines.append(f"| {ARM_LABEL[a]} − {ARM_LABEL[b]} | {key} | {n} | {text} | "
                     f"{'' if p is None else f'{p:.3f}'} | {adj} |")
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
    parser.add_argument("--curriculum-out", default=str(ROOT / "bench" / "results" / "curriculum"),
                        help="the curriculum grid's results (its summaries/ folder)")
    args = parser.parse_args()
    out = Path(args.out)
    runs = load(out)
    curriculum = load(Path(args.curriculum_out)) if (Path(args.curriculum_out) / "summaries").is_dir() else []
    spread = [r for r in runs if r.get("grid", "spread") == "spread"]
    ablations = [r for r in runs if r.get("grid") == "ablations"]
    tag = [r for r in runs if r["task"] == "tag"]
    blocks = {"spread": spread_table(spread), "seeds": seeds_table(spread), "tests": tests_table(spread)}
    if ablations:
        blocks["ablations"] = ablation_table(ablations, [r for r in spread if r["algorithm"] == "cmcl"]
                                             + [r for r in runs if r.get("grid") == "ablation_reference"])
    if tag:
        blocks["tag"], blocks["tagtests"] = tag_table(tag), tag_tests_table(tag)
    if curriculum:
        blocks["curriculum"], blocks["curriculumtests"] = curriculum_table(curriculum), curriculum_tests(curriculum)
    for name, body in blocks.items():
        print(f"{name}:\n{body}\n")
    from reproduce_figures import figures  # a sibling script; it imports this module's constants

    for png in figures(runs, out / "figures"):
        print(f"figure: {png.relative_to(ROOT) if png.is_relative_to(ROOT) else png}")
    if args.update:
        update(Path(args.update), blocks)


if __name__ == "__main__":
    sys.exit(main())

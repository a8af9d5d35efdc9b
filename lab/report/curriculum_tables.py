"""The tables of the curriculum grids (the protocol of lab/RESULTS.md): per arm the learning measures,
the stalls and the sampling distribution over training; then the pre-registered tests, one primary comparison
unadjusted and every other one Holm-corrected. Navigation grids are measured on coverage, the predator-prey grid on
the predators' win (an episode with a capture): TaskMeasures names the fields of each."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from experiments.grids import CURRICULUM_ARMS
from experiments.labels import ARM_LABEL
from experiments.provenance import cell_versions
from lab.report.stats import TIMES, detectable, difference, fmt, fmt_time, holm, logrank_p, spread

ALPHA = 0.05  # the level of the protocol's tests: the primary's, and the Holm family's
STALL = (0.65, 0.85)  # final MA coverage of a run stuck at about three landmarks of four


@dataclass(frozen=True)
class TaskMeasures:
    """The summary fields a curriculum grid's tables read on one task. area: the area under the training curve, the
    primary comparison's measure (in [0, 1]); held_out: the held-out rate tested; time: the censored episodes to the
    curve's moving average 0.9; columns: (header, field, digits) of the per-arm table; stalls: whether the table
    counts runs stalled at about three landmarks of four (navigation only)."""

    area: str
    held_out: str
    time: str
    columns: tuple[tuple[str, str, int], ...]
    stalls: bool

    def comparisons(self) -> list[tuple[str, str, str]]:
        """(arm, arm, field) of the protocol's tests: the primary comparison first (CMCL against MADDPG on the area),
        then the ones Holm-corrected together."""
        return [("cmcl", "maddpg", self.area), ("cmcl", "per", self.area), ("cmcl", "acl", self.area),
                ("cmcl", "cmcl_permuted", self.area), ("cmcl", "cmcl_anti", self.area), ("acl", "maddpg", self.area),
                ("per", "maddpg", self.area), ("cmcl", "maddpg", self.held_out), ("cmcl", "maddpg", self.time)]


NAVIGATION = TaskMeasures("auc_coverage", "held_out_success", "episodes_to_90",
                          (("area under coverage", "auc_coverage", 3), ("held-out coverage", "held_out_coverage", 3),
                           ("held-out success", "held_out_success", 3), ("episodes to MA 0.9", "episodes_to_90", 0)),
                          stalls=True)
# held-out against random prey: every run trains its own prey, so a win against "its trained prey" is against a
# different opponent in each run
PREDATOR_PREY = TaskMeasures("auc_predator_win", "win_vs_random_prey", "episodes_to_win_90",
                             (("area under predator win", "auc_predator_win", 3),
                              ("final MA win", "final_ma_predator_win", 3),
                              ("held-out win vs random prey", "win_vs_random_prey", 3),
                              ("held-out win vs its trained prey", "win_vs_trained_prey", 3),
                              ("episodes to MA win 0.9", "episodes_to_win_90", 0)), stalls=False)


def task_measures(runs: list[dict[str, Any]]) -> TaskMeasures:
    """The measures of the grid these runs belong to (one task per grid)."""
    return PREDATOR_PREY if runs and runs[0].get("task") == "tag" else NAVIGATION


def curriculum_table(runs: list[dict[str, Any]]) -> str:
    """The curriculum grid per arm: learning measures, stalls (navigation), and the sampling distribution over
    training."""
    measures = task_measures(runs)
    keys = measures.columns
    stall_header = " stalled at ~3 of 4 |" if measures.stalls else ""
    lines = ["| arm | seeds | " + " | ".join(k[0] for k in keys) + f" |{stall_header} ESS over training | "
             "ESS, first quarter | reward-bearing rows, first quarter: sampled / buffer | wall s, mean (min..max) |",
             "| --- " * (len(keys) + 6 + measures.stalls) + "|"]
    for arm in CURRICULUM_ARMS:
        rs = sorted((r for r in runs if r.get("arm") == arm), key=lambda r: r["seed"])
        if not rs:
            continue
        stalled = f" {sum(STALL[0] <= r['final_ma_coverage'] <= STALL[1] for r in rs)}/{len(rs)} |" \
            if measures.stalls else ""
        sampled, buffer = (np.mean([first_quarter(r, k) for r in rs]) for k in ("reward_rows_sampled",
                                                                                 "reward_rows_buffer"))
        lines.append(f"| {ARM_LABEL[arm]} | {len(rs)} | " + " | ".join(fmt([r.get(k) for r in rs], d, k)
                                                                   for _, k, d in keys)
                     + f" |{stalled} {fmt([r['ess_mean'] for r in rs], 2, 'auc_coverage')} | "
                     f"{fmt([r['ess_first_quarter'] for r in rs], 2, 'auc_coverage')} | {sampled:.3f} / {buffer:.3f} | "
                     f"{spread([r['wall_s'] for r in rs])} |")  # seconds are skewed by load: no t interval
    return "\n".join(lines)


def curve_mean(run: dict[str, Any], key: str, rows: np.ndarray) -> float:
    """Mean of a run's sampling_curve column over the progress rows where `rows` (bool[rows]) holds; nan if none."""
    values = np.asarray(run["sampling_curve"][key], dtype=np.float64)[rows]
    return float(values.mean()) if values.size else float("nan")


def first_quarter(run: dict[str, Any], key: str) -> float:
    """Mean of a run's sampling_curve column over its first quarter of episodes (λ < 0.5 at the default stride,
    where the curriculum can exclude rows)."""
    return curve_mean(run, key, np.asarray(run["sampling_curve"]["episode"]) <= run["budget"] / 4)


# The grids of CMCL on the harder task with one setting changed (experiments.grids.HARD_SETTING_GRIDS; lab/RESULTS.md,
# "The λ schedule on the harder task", "The curiosity weight on the harder task"): grid -> (the arms of its table in
# order, beside the harder task's MADDPG and default CMCL; its tests, all Holm-corrected together: no primary)
AREA = "auc_coverage"
SETTING_TABLES: dict[str, tuple[tuple[str, ...], list[tuple[str, str, str]]]] = {
    "curriculum_stride": (("maddpg", "cmcl_stride_x2", "cmcl", "cmcl_stride_half"),
                          [("cmcl_stride_x2", "cmcl", AREA), ("cmcl_stride_half", "cmcl", AREA),
                           ("cmcl_stride_x2", "maddpg", AREA)]),
    "curriculum_eta": (("maddpg", "cmcl", "cmcl_eta1"), [("cmcl_eta1", "cmcl", AREA), ("cmcl_eta1", "maddpg", AREA)]),
}


def while_excluding(run: dict[str, Any], key: str) -> float:
    """Mean of a run's sampling_curve column over the progress rows with λ < 0.5 (where KP can exclude rows)."""
    return curve_mean(run, key, np.asarray(run["sampling_curve"]["lambda"]) < 0.5)


def last_excluding_episode(run: dict[str, Any]) -> float:
    """The last progress row's episode with λ < 0.5 (0 when λ starts at 0.5 or above)."""
    curve = run["sampling_curve"]
    return float(max((e for lam, e in zip(curve["lambda"], curve["episode"], strict=True) if lam < 0.5), default=0))


def setting_table(runs: list[dict[str, Any]], arms: tuple[str, ...]) -> str:
    """A harder-task settings grid per arm of `arms`: learning measures, how long λ stays below 0.5 and the sampling
    while it does."""
    lines = ["| arm | seeds | area under coverage | held-out coverage | held-out success | episodes to MA 0.5 | "
             "episodes to MA 0.9 | stalled at ~3 of 4 | last progress row with λ < 0.5 | ESS while λ < 0.5 | "
             "reward-bearing rows while λ < 0.5: sampled / buffer |", "| --- " * 11 + "|"]
    for arm in arms:
        rs = sorted((r for r in runs if r.get("arm") == arm), key=lambda r: r["seed"])
        if not rs:
            continue
        stalled = sum(STALL[0] <= r["final_ma_coverage"] <= STALL[1] for r in rs)
        ess, sampled, buffer = (np.nanmean([while_excluding(r, k) for r in rs])
                                for k in ("ess", "reward_rows_sampled", "reward_rows_buffer"))
        curriculum = "— | — | —" if arm == "maddpg" else \
            f"{np.mean([last_excluding_episode(r) for r in rs]):,.0f} | {ess:.2f} | {sampled:.3f} / {buffer:.3f}"
        lines.append(f"| {ARM_LABEL[arm]} | {len(rs)} | " + " | ".join(
            fmt([r[k] for r in rs], d, k) for k, d in (("auc_coverage", 3), ("held_out_coverage", 3),
                                                       ("held_out_success", 3), ("episodes_to_50", 0),
                                                       ("episodes_to_90", 0)))
                     + f" | {stalled}/{len(rs)} | {curriculum} |")
    return "\n".join(lines)


@dataclass(frozen=True)
class Test:
    """One row of a curriculum grid's tests. a, b: the arms (a − b); key: the measure; seeds: (runs of a, runs of b);
    code: the code versions of its runs (experiments.provenance.cell_versions); text: the difference as printed, or
    why it was not tested; difference: mean(a) − mean(b) (None for a time to threshold or a test not run); p: the
    test's p-value (None when not run); adjusted: Holm's p (None for the primary comparison or a test not run);
    primary: the protocol's named comparison; level: the α it is judged at; detectable: the smallest difference of
    means its test detects with 80% power at that level (None for a time or a test not run); mixed: not run because
    its runs ran different code (a test not run otherwise lacks its runs)."""

    a: str
    b: str
    key: str
    seeds: tuple[int, int]
    code: str
    text: str
    difference: float | None
    p: float | None
    adjusted: float | None
    primary: bool
    level: float
    detectable: float | None
    mixed: bool

    @property
    def testable(self) -> bool:
        return self.p is not None


def curriculum_test_rows(runs: list[dict[str, Any]],
                         comparisons: list[tuple[str, str, str]] | None = None) -> list[Test]:
    """The protocol's tests: the primary comparison unadjusted, every other one Holm-corrected; times to MA 0.9 by
    KM medians and a log-rank test. comparisons: (arm, arm, field) to test instead of the task's protocol, all
    Holm-corrected together (no primary). Each difference of means also gets the smallest difference its test detects
    with 80% power at the α it is judged at: ALPHA for the primary; for the Holm-corrected ones the family's ALPHA / m,
    the level of Holm's first step (a later step's level depends on the p-values themselves; a difference this large
    is detected with 80% power whatever the other tests show)."""
    primary = comparisons is None
    comparisons = task_measures(runs).comparisons() if comparisons is None else comparisons
    by_arm = {arm: [r for r in runs if r.get("arm") == arm] for pair in comparisons for arm in pair[:2]}
    rows = []
    for a, b, key in comparisons:
        ra, rb = by_arm[a], by_arm[b]
        code, testable = cell_versions(ra + rb)
        if len(ra) < 2 or len(rb) < 2 or not testable:
            rows.append((a, b, key, code, "n/a (fewer than 2 runs)" if testable else "not tested: code versions mixed",
                         None, None, not testable))
            continue
        if key in TIMES:
            ta, tb = [r[key] for r in ra], [r[key] for r in rb]
            rows.append((a, b, key, code, f"{fmt_time(ta)} vs {fmt_time(tb)}", None,
                         logrank_p(ta, tb, ra[0]["budget"]), False))
        else:
            d, lo, hi, p = difference([r[key] for r in ra], [r[key] for r in rb])
            rows.append((a, b, key, code, f"{d:+.3f} [{lo:+.3f}, {hi:+.3f}]", d, p, False))
    pvalues = [row[-2] for row in rows]
    # Holm over the whole pre-registered family: a test without its runs yet counts as p = 1 (conservative)
    tested = [1.0 if p is None else p for p in (pvalues[1:] if primary else pvalues)]
    adjusted = [None] * primary + holm(tested)
    levels = [ALPHA] * primary + [ALPHA / len(tested)] * len(tested)
    out = []
    for i, (a, b, key, code, text, d, p, mixed) in enumerate(rows):
        mde = None if p is None or key in TIMES else detectable([r[key] for r in by_arm[a]],
                                                                [r[key] for r in by_arm[b]], levels[i])
        out.append(Test(a, b, key, (len(by_arm[a]), len(by_arm[b])), code, text, d, p,
                        None if p is None or (primary and i == 0) else adjusted[i], primary and i == 0, levels[i],
                        mde, mixed))
    return out


def curriculum_tests(runs: list[dict[str, Any]], comparisons: list[tuple[str, str, str]] | None = None) -> str:
    """The protocol's tests (curriculum_test_rows) as a markdown table."""
    return format_tests(curriculum_test_rows(runs, comparisons))


def format_tests(tests: list[Test]) -> str:
    """Rows of curriculum_test_rows as a markdown table."""
    lines = ["| comparison | measure | seeds | code | difference [bootstrap 95%] | p | p (Holm) | detectable with 80% "
             "power (α) |", "| --- " * 8 + "|"]
    for t in tests:
        adj = "primary" if t.primary else "" if t.p is None else f"{t.adjusted:.3f}"
        mde = "" if t.p is None else "—" if t.detectable is None else f"{t.detectable:.3f} (α {t.level:.2g})"
        lines.append(f"| {ARM_LABEL[t.a]} − {ARM_LABEL[t.b]} | {t.key} | {t.seeds[0]} vs {t.seeds[1]} | {t.code} | "
                     f"{t.text} | {'' if t.p is None else f'{t.p:.3f}'} | {adj} | {mde} |")
    return "\n".join(lines)

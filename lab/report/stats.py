"""Statistics over the runs of a grid: intervals of a mean over seeds, censored times to a threshold, tests.

Intervals: rates (coverage, success, win rates, area under coverage: all in [0, 1]) get a percentile bootstrap
interval of the mean over seeds (BOOTSTRAP resamples, fixed seed), which stays inside [0, 1]; unbounded measures
(reward, seconds) a Student-t interval. Episodes to a moving-average threshold are censored at the budget (a run
that never gets there is not dropped): Kaplan-Meier median and the number of runs that got there, compared by a
log-rank test.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

RATES = ("held_out_coverage", "held_out_success", "auc_coverage", "final_ma_coverage", "final_ma_success",
         "final_ma_predator_win", "win_vs_trained_prey", "win_vs_random_prey", "auc_predator_win")  # measures in [0, 1]
# censored at the run's budget when never reached (None)
TIMES = ("episodes_to_50", "episodes_to_90", "episodes_to_win_50", "episodes_to_win_90")
BOOTSTRAP = 10_000


def mean_ci(values: list[float]) -> tuple[float, float]:
    """(mean, half-width of the two-sided 95% t interval); half-width nan for fewer than 2 values."""
    x = np.asarray(values, dtype=np.float64)
    if x.size < 2:
        return float(x.mean()) if x.size else float("nan"), float("nan")
    return float(x.mean()), float(stats.t.ppf(0.975, x.size - 1) * x.std(ddof=1) / np.sqrt(x.size))


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


def bootstrap_band(rows: np.ndarray, resamples: int = 2_000,
                   seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean, low, high) per column of rows (float[runs, points], NaN where a run has no value): the mean over the
    runs with a value and the percentile bootstrap 95% interval of it (runs resampled, fixed seed). Like
    bootstrap_ci it stays within the runs' values, so a rate's band stays in [0, 1]; NaN where fewer than 2 runs have
    a value (no band) or no run has one (no mean)."""
    y = np.asarray(rows, dtype=np.float64)
    finite = np.isfinite(y)
    count = finite.sum(0)
    mean = np.where(count > 0, np.where(finite, y, 0.0).sum(0) / np.maximum(count, 1), np.nan)
    idx = np.random.default_rng(seed).integers(0, y.shape[0], (resamples, y.shape[0]))
    drawn, got = np.where(finite, y, 0.0)[idx].sum(1), finite[idx].sum(1)  # [resamples, points]
    means = np.where(got > 0, drawn / np.maximum(got, 1), np.nan)
    with np.errstate(all="ignore"):
        lo, hi = np.nanpercentile(np.where(np.isnan(means).all(0), 0.0, means), [2.5, 97.5], axis=0)
    several = count > 1
    return mean, np.where(several, lo, np.nan), np.where(several, hi, np.nan)


def kaplan_meier(times: list[float | None]) -> tuple[float | None, int, bool]:
    """Kaplan-Meier median of a time to threshold, how many runs reached it, and whether that median is only a lower
    bound. times: one per run, None = not reached within the run's budget (right-censored there; every run of a table
    has the same budget, so every censoring comes after every event). Median None when the survival curve never falls
    to 0.5; a lower bound when it falls to exactly 0.5 at the last event (e.g. the fifth of 10 runs) and the rest are
    censored: the median is then that event's time or any later one."""
    events = sorted(t for t in times if t is not None)
    at_risk, surv = len(times), 1.0
    for i, t in enumerate(events):  # product-limit estimate: one event at a time, nobody censored before the budget
        surv *= 1 - 1 / at_risk
        at_risk -= 1
        if surv <= 0.5 + 1e-12:
            return float(t), len(events), i == len(events) - 1 and at_risk > 0 and surv >= 0.5 - 1e-12
    return None, len(events), False


def km_median(times: list[float | None]) -> tuple[float | None, int]:
    """Kaplan-Meier median of a time to threshold and how many runs reached it (kaplan_meier without the bound)."""
    return kaplan_meier(times)[:2]


def median_text(times: list[float | None], digits: int = 0, missing: str = "not reached", grouped: bool = False
                ) -> str:
    """The Kaplan-Meier median as printed: 'M', '≥ M' when it is only a lower bound, `missing` when not reached;
    grouped: thousands separated as in prose ('10,949')."""
    med, _, lower = kaplan_meier(times)
    return missing if med is None else f"{'≥ ' if lower else ''}{med:{',' if grouped else ''}.{digits}f}"


def fmt_time(values: list[float | None], digits: int = 0) -> str:
    """'KM median M (k/n reached)' of a censored time to threshold ('KM median ≥ M' for a lower bound)."""
    text, k = median_text(values, digits, missing=""), kaplan_meier(values)[1]
    return f"{f'KM median {text}' if text else 'not reached'} ({k}/{len(values)} reached)"


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


def detectable(a: list[float], b: list[float], alpha: float = 0.05, power: float = 0.8) -> float:
    """The smallest true difference of means that Welch's two-sided test at level `alpha` detects with probability
    `power`, at the standard deviations and seeds observed: (t[1 − α/2] + t[power]) · standard error, at Welch's
    degrees of freedom."""
    x, y = np.asarray(a, float), np.asarray(b, float)
    va, vb = x.var(ddof=1) / x.size, y.var(ddof=1) / y.size
    dof = (va + vb) ** 2 / (va ** 2 / (x.size - 1) + vb ** 2 / (y.size - 1)) if va + vb > 0 else x.size + y.size - 2
    return float((stats.t.ppf(1 - alpha / 2, dof) + stats.t.ppf(power, dof)) * np.sqrt(va + vb))


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


def welch_test(a: list[float], b: list[float]) -> tuple[float, float, float] | None:
    """(mean(a) − mean(b), half-width of its 95% Welch interval, two-sided p) by Welch's unequal-variance t-test;
    None for fewer than 2 values in either sample; half-width and p nan when neither sample has any spread."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.size < 2 or b.size < 2:
        return None
    va, vb = a.var(ddof=1) / a.size, b.var(ddof=1) / b.size
    diff, se = float(a.mean() - b.mean()), np.sqrt(va + vb)
    if se == 0:
        return diff, float("nan"), float("nan")
    dof = (va + vb) ** 2 / (va ** 2 / (a.size - 1) + vb ** 2 / (b.size - 1))
    return diff, float(stats.t.ppf(0.975, dof) * se), float(stats.ttest_ind(a, b, equal_var=False).pvalue)


def welch(a: list[float], b: list[float], digits: int = 3) -> str:
    """'Δ = mean(a) − mean(b) [95% CI], p' by Welch's unequal-variance t-test (two-sided)."""
    test = welch_test(a, b)
    if test is None:
        return "n/a"
    diff, half, p = test
    if np.isnan(half):
        return f"{diff:+.{digits}f} (no spread)"
    return f"{diff:+.{digits}f} [{diff - half:+.{digits}f}, {diff + half:+.{digits}f}], p = {p:.3f}"


def paired_test(variant: dict[int, float], reference: dict[int, float]) -> tuple[float, float, float, int]:
    """(mean of variant − reference over the seeds both have, half-width of its 95% t interval, two-sided paired p,
    number of seeds); half-width and p nan for fewer than 2 seeds, p nan when every difference is the same."""
    seeds = sorted(set(variant) & set(reference))
    d = np.asarray([variant[s] - reference[s] for s in seeds], dtype=np.float64)
    if d.size < 2:
        return float(d.mean()) if d.size else float("nan"), float("nan"), float("nan"), int(d.size)
    m, h = mean_ci(list(d))
    p = float("nan") if np.all(d == d[0]) else float(stats.ttest_1samp(d, 0.0).pvalue)
    return m, h, p, int(d.size)


def paired(variant: dict[int, float], reference: dict[int, float], digits: int = 3) -> str:
    """'Δ = mean(variant − reference) [95% CI], p' over the seeds both have, by a paired two-sided t-test.

    variant, reference: {seed: value}. Inline runs are deterministic for a seed, so a variant and the reference of
    the same seed share their initial weights and worlds until the changed setting first acts."""
    m, h, p, n = paired_test(variant, reference)
    if n < 2:
        return f"n/a ({n} paired seed{'s' if n != 1 else ''})"
    if np.isnan(p):
        return f"{m:+.{digits}f} (no spread, n = {n})"
    return f"{m:+.{digits}f} [{m - h:+.{digits}f}, {m + h:+.{digits}f}], p = {p:.3f}, n = {n}"


def difference(a: list[float], b: list[float], seed: int = 0,
               alpha: float = 0.05) -> tuple[float, float, float, float]:
    """(mean(a) − mean(b), bootstrap 1 − `alpha` interval of it (each arm resampled on its own; 95% unless a
    corrected level is asked for), Welch p)."""
    x, y = np.asarray(a, float), np.asarray(b, float)
    rng = np.random.default_rng(seed)
    boot = (x[rng.integers(0, x.size, (BOOTSTRAP, x.size))].mean(1)
            - y[rng.integers(0, y.size, (BOOTSTRAP, y.size))].mean(1))
    tail = 50.0 * alpha
    lo, hi = np.percentile(boot, [tail, 100.0 - tail])
    p = float(stats.ttest_ind(x, y, equal_var=False).pvalue) if x.std() + y.std() > 0 else 1.0
    return float(x.mean() - y.mean()), float(lo), float(hi), p


def spread(values: list[float | None], pattern: str = "{:.0f}") -> str:
    """'mean (min..max)' over seeds; runs that never reached the target are counted and shown as 'n/k never'
    (the time-to-solve tables, a few seeds per cell)."""
    got = [v for v in values if v is not None]
    never = len(values) - len(got)
    if not got:
        return f"never ({never}/{len(values)})"
    text = pattern.format(np.mean(got)) + (f" ({pattern.format(min(got))}..{pattern.format(max(got))})"
                                           if len(got) > 1 else "")
    return text + (f", {never}/{len(values)} never" if never else "")

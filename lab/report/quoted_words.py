"""How the blocks of lab.report.quoted say a test and a spread of numbers in words, shared by every grid's
sentences: a p value, a signed difference, a Kaplan-Meier median with the runs that got there, a range, a list, and
a difference-of-means test as a verdict (withdrawn for mixed code, "not shown" at p ≥ α). Reads no results.
"""

from __future__ import annotations

from lab.report.curriculum_tables import ALPHA, Test
from lab.report.stats import kaplan_meier, median_text

NO_RUNS = "no runs yet"  # a block whose grid has no summaries under the results root


def untested(test: Test, where: str = "") -> str:
    """Why a test is quoted without its number (after 'is' / 'are'): 'withdrawn until its grid is re-run at one commit
    (its runs ran mixed code versions; <where>)', or 'not run yet (fewer than 2 runs per arm; <where>)'."""
    why = "withdrawn until its grid is re-run at one commit (its runs ran mixed code versions" if test.mixed else \
        "not run yet (fewer than 2 runs per arm"
    return why + (f"; {where})" if where else ")")


def p_text(p: float) -> str:
    """'p = 0.067', 'p = 0.0014' (two significant digits below 0.01), 'p < 0.0001'."""
    return "p < 0.0001" if p < 1e-4 else f"p = {p:.2g}" if p < 0.01 else f"p = {p:.3f}"


def signed(value: float, digits: int = 3) -> str:
    """'+0.032', '−0.063' (a minus sign, as in prose)."""
    return f"{value:+.{digits}f}".replace("-", "−")


def km_text(times: list[float | None]) -> str:
    """A Kaplan-Meier median of episodes with the runs that got there: '10,949 (10/10)', '≥ 18,952 (5/10)',
    'not reached (3/10)'."""
    return f"{median_text(times, grouped=True)} ({kaplan_meier(times)[1]}/{len(times)})"


def span(values: list[float], digits: int) -> str:
    """'min–max' of values ('v' when they agree at these digits)."""
    lo, hi = f"{min(values):.{digits}f}", f"{max(values):.{digits}f}"
    return lo if lo == hi else f"{lo}–{hi}"


def joined(items: list[str]) -> str:
    """'a', 'a and b', 'a, b and c'."""
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def seeds_text(tests: list[Test]) -> str:
    """'10 seeds per arm' over the arms of these tests ('5–10 seeds per arm' when they differ)."""
    counts = [n for t in tests for n in t.seeds]
    return f"{span(counts, 0)} seeds per arm"


def verdict(test: Test, where: str = "") -> str:
    """A difference-of-means test in words: 'learns later on predator-prey (−0.029, p = 0.0014)', 'is not shown to
    differ (...)', 'learns sooner (...)'; the p it is judged by is Holm's for a Holm-corrected test."""
    p = test.p if test.primary or test.adjusted is None else test.adjusted
    words = ("learns later" if test.difference < 0 else "learns sooner") if p < ALPHA else "is not shown to differ"
    return f"{words}{' ' + where if where else ''} ({signed(test.difference)}, {'' if test.primary else 'Holm '}" \
           f"{p_text(p)})"

"""The rule confirmation (protocol in lab/RESULTS.md, "the confirmation's protocol"): the rules the screen
selected, MADDPG and each rule's permuted control on the harder task, 20 seeds per arm, or 10 for a rule the interim
look stopped (experiments.confirm_arms.stopped_at_interim).

Per arm (`confirm_table`): the screen's columns (lab.report.screen_table.arm_table). The tests (`confirm_tests`),
curriculum_tables' machinery in two Holm families at α = 0.05:

* primary: rule − MADDPG in area under the training coverage curve, one test per chosen rule, Holm across them;
* secondary, one family: per rule, rule − its permuted control in area, held-out success rule − MADDPG, and
  episodes to MA 0.9 rule against MADDPG (log-rank).

Each difference of means carries the smallest difference it detects with 80% power at its family's α / m. Then the
goal's verdict per rule (`verdicts`), once every arm has its seeds: "goal not met" for a rule the interim look
stopped; else "meets the goal" only if the area difference
over MADDPG is at least GOAL, its Holm-corrected interval (the bootstrap interval at 1 − α / m, the level of Holm's
first step in the primary family) lies above 0, and rule − permuted control is positive with a Holm p below α in the
secondary family; otherwise "goal not met" and why. `recommended` is the rule the protocol's "Then" makes the
project's curriculum (the one that meets the goal with the largest gain, else None), and `confirm_decision` README.md's
sentence on it and on what `make run` trains (tests/test_confirm.py checks that `make run` follows it).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from experiments.confirm_arms import (
    CONFIRM_REFERENCES,
    CONFIRM_SEEDS,
    INTERIM_SEEDS,
    confirm_arms,
    stopped_at_interim,
)
from experiments.labels import ARM_LABEL, PERMUTED
from lab.report.curriculum_tables import ALPHA, NAVIGATION, Test, curriculum_test_rows, format_tests
from lab.report.quoted_words import signed
from lab.report.screen_table import arm_table
from lab.report.stats import difference

GOAL = 0.10  # the least area under coverage a rule must gain over MADDPG (the goal written before any run)
MEETS = "**meets the goal**"  # a rule's verdict when all three conditions hold


def confirm_roles(rules: Sequence[str]) -> dict[str, str]:
    """arm -> its role in the confirmation ("rule", "permuted control", "reference"), in table order."""
    return {arm: "reference" if arm in CONFIRM_REFERENCES else "permuted control" if arm.endswith(PERMUTED)
            else "rule" for arm in confirm_arms(rules)}


def confirm_table(runs: list[dict[str, Any]], rules: Sequence[str]) -> str:
    """The confirmation per arm: the screen's columns, with each arm's role and code."""
    return arm_table(runs, confirm_roles(rules))


def families(rules: Sequence[str]) -> tuple[list[tuple[str, str, str]], list[tuple[str, str, str]]]:
    """(primary, secondary) comparisons (arm, arm, field) of the protocol, each one Holm family."""
    m = NAVIGATION
    primary = [(rule, "maddpg", m.area) for rule in rules]
    secondary = [c for rule in rules for c in ((rule, f"{rule}{PERMUTED}", m.area), (rule, "maddpg", m.held_out),
                                               (rule, "maddpg", m.time))]
    return primary, secondary


def complete(runs: list[dict[str, Any]], rules: Sequence[str]) -> bool:
    """Whether every arm of the confirmation has its seeds: INTERIM_SEEDS for the arms of a rule the interim look
    stopped, CONFIRM_SEEDS for the others (MADDPG's only INTERIM_SEEDS when every rule stopped)."""
    stopped = stopped_at_interim(runs, rules)
    if stopped is None:
        return False
    going = [rule for rule in rules if rule not in stopped]
    return all({r["seed"] for r in runs if r.get("arm") == arm} >= set(CONFIRM_SEEDS) for arm in confirm_arms(going)) \
        if going else True


def verdict(primary: Test, control: Test, interval: tuple[float, float] | None, stopped: bool = False) -> str:
    """The goal's verdict on a rule from its primary test, its test against its permuted control and its
    Holm-corrected interval (None when its runs ran mixed code); `stopped`: the interim look stopped the rule."""
    if stopped:
        return (f"goal not met: stopped at the interim look (seeds {INTERIM_SEEDS[0]}–{INTERIM_SEEDS[-1]}), its area "
                f"{signed(primary.difference)} over MADDPG's, not above it")
    if interval is None:
        return "goal not met: not tested, its runs ran different code (code versions mixed)"
    reasons = []
    if primary.difference < GOAL:
        reasons.append(f"the area is {signed(primary.difference)} over MADDPG's, less than {signed(GOAL, 2)}")
    if interval[0] <= 0:
        reasons.append(f"the Holm-corrected interval [{signed(interval[0])}, {signed(interval[1])}] does not lie "
                       "above 0")
    if not (control.difference > 0 and control.adjusted < ALPHA):
        reasons.append(f"not shown above its permuted control ({signed(control.difference)}, Holm p = "
                       f"{control.adjusted:.3f})")
    return MEETS if not reasons else "goal not met: " + "; ".join(reasons)


def rule_verdicts(runs: list[dict[str, Any]], rules: Sequence[str], primary: list[Test], secondary: list[Test]
                  ) -> list[tuple[str, Test, Test, tuple[float, float] | None, str]] | None:
    """Per rule (rule, primary test, its test against its permuted control, Holm-corrected interval or None, verdict),
    or None while the confirmation is not complete (`complete`)."""
    if not complete(runs, rules):
        return None
    level = primary[0].level if primary else ALPHA
    stopped = stopped_at_interim(runs, rules) or ()
    out = []
    for rule, test in zip(rules, primary, strict=True):
        control = next(t for t in secondary if t.a == rule and t.b == f"{rule}{PERMUTED}")
        interval = None
        if not (test.mixed or control.mixed):
            areas = [[r[test.key] for r in runs if r.get("arm") == arm] for arm in (rule, "maddpg")]
            interval = difference(*areas, alpha=level)[1:3]
        out.append((rule, test, control, interval, verdict(test, control, interval, rule in stopped)))
    return out


def verdicts(runs: list[dict[str, Any]], rules: Sequence[str], primary: list[Test], secondary: list[Test]) -> str:
    """One row per rule: its area over MADDPG, the Holm-corrected interval, its difference from its permuted control
    and the verdict (which waits until every arm has its seeds)."""
    level = primary[0].level if primary else ALPHA
    lines = [f"| rule | area − MADDPG [bootstrap 95%] | Holm-corrected interval ({100 * (1 - level):.4g}%) | "
             "− its permuted control (Holm p) | verdict |", "| --- " * 5 + "|"]
    ready = rule_verdicts(runs, rules, primary, secondary)
    if ready is None:
        return "\n".join(lines + [f"| {ARM_LABEL[rule]} | | | | waits for {len(CONFIRM_SEEDS)} seeds per arm (or "
                                  f"{len(INTERIM_SEEDS)} if the interim look stops it) |" for rule in rules])
    for rule, test, control, interval, said in ready:
        lines.append(f"| {ARM_LABEL[rule]} | {test.text} | "
                     + ("" if interval is None else f"[{signed(interval[0])}, {signed(interval[1])}]") + " | "
                     + (control.text if interval is None else f"{signed(control.difference)} ({control.adjusted:.3f})")
                     + f" | {said} |")
    return "\n".join(lines)


def recommended(runs: list[dict[str, Any]], rules: Sequence[str]) -> str | None:
    """The rule the confirmation recommends: of the rules that meet the goal, the one with the largest area gain over
    MADDPG (the protocol's "Then"); None while the confirmation is incomplete or when no rule meets it."""
    first, second = families(rules)
    ready = rule_verdicts(runs, rules, curriculum_test_rows(runs, first), curriculum_test_rows(runs, second))
    met = [(test.difference, rule) for rule, test, _, _, said in ready or () if said == MEETS]
    return max(met)[1] if met else None


def confirm_decision(runs: list[dict[str, Any]], rules: Sequence[str], code: bool = True) -> str:
    """README.md's sentence on the recommended curriculum, from the confirmation's summaries: how far it is while
    incomplete; then each rule's gain over MADDPG, its difference from its permuted control and its verdict, and
    what `make run` trains as a consequence (the rule that meets the goal, else uniform replay); `code`: name the
    commits the runs were made at (the record's form; the README's leaves them to the record)."""
    names = " and ".join(ARM_LABEL[rule] for rule in rules)
    first, second = families(rules)
    primary, secondary = curriculum_test_rows(runs, first), curriculum_test_rows(runs, second)
    ready = rule_verdicts(runs, rules, primary, secondary)
    if ready is None:
        per_arm = "; ".join(f"{sum(r.get('arm') == arm for r in runs)} of {ARM_LABEL[arm]}"
                            for arm in confirm_arms(rules))
        return (f"The confirmation of the screen's choice ({names}) against uniform replay on the harder task is under "
                f"way (runs in: {per_arm}; {len(CONFIRM_SEEDS)} seeds per arm planned, {len(INTERIM_SEEDS)} for a "
                "rule the interim look stops): no verdict yet, so no rule is recommended over uniform replay, and "
                "`make run` trains uniform replay (MADDPG).")
    parts = []
    for rule, test, control, _, said in ready:
        against = control.text if control.difference is None else \
            f"{signed(control.difference)} against its permuted control (Holm p = {control.adjusted:.3f})"
        parts.append(f"{ARM_LABEL[rule]}: area {test.text.replace('-', '−')} over MADDPG, {against}; {said.strip('*')}")
    best = recommended(runs, rules)
    then = (f"{ARM_LABEL[best]} is the recommended curriculum, and `make run` trains it" if best else
            "so no rule is recommended over uniform replay, and `make run` trains uniform replay (MADDPG)")
    seeds = sorted({len({r["seed"] for r in runs if r.get("arm") == arm}) for arm in confirm_arms(rules)})
    commits = f", code {', '.join(sorted({t.code for t in primary}))}" if code else ""
    return (f"The confirmation on the harder task ({'–'.join(map(str, seeds))} seeds per arm{commits}): "
            + "; ".join(parts) + f". {then[0].upper()}{then[1:]}.")


def confirm_tests(runs: list[dict[str, Any]], rules: Sequence[str]) -> str:
    """The protocol's two Holm families as tables, then the goal's verdict per rule."""
    first, second = families(rules)
    primary, secondary = curriculum_test_rows(runs, first), curriculum_test_rows(runs, second)
    return (f"Primary: rule − MADDPG in area under coverage, Holm across the {len(rules)} chosen rule"
            f"{'s' * (len(rules) != 1)} (α = {ALPHA}).\n\n{format_tests(primary)}\n\n"
            f"Secondary, one Holm family of {len(second)} tests (α = {ALPHA}).\n\n{format_tests(secondary)}\n\n"
            f"The goal: area at least {GOAL:.2f} above MADDPG's, the Holm-corrected interval above 0, and above the "
            f"rule's own permuted control.\n\n{verdicts(runs, rules, primary, secondary)}")

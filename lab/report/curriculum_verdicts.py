"""The verdicts of a navigation curriculum grid's protocol, drawn from its tests (lab.report.curriculum_tables), as
the table lab/RESULTS.md prints under the grid's tests (block curriculumhardverdicts: the harder task's grid, the
grid re-run at one commit). One row per question of the protocol: the primary (CMCL − MADDPG in the area
under the training coverage curve, Welch), the paper's Fig. 8b (CMCL against PER-MADDPG and ACL), whether CMCL ends
better or reaches MA 0.9 sooner, and the two controls (the curriculum's information: the permuted control; its
direction: the anti-curriculum), each judged at the level its test is judged at (the primary unadjusted, the rest by
Holm's p over the family). The settings grids on the harder task (blocks curriculumstrideverdicts and
curriculumetaverdicts: the λ stride and η, SETTING_TABLES) get one question per comparison of their Holm family
(SETTING_QUESTIONS). A question whose tests were not run (mixed code, or too few runs) says so instead of a verdict.
Reads only the runs it is given.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from lab.report.curriculum_tables import ALPHA, SETTING_TABLES, Test, curriculum_test_rows
from lab.report.quoted_words import NO_RUNS, km_text, p_text, signed
from lab.report.stats import kaplan_meier


def shown(test: Test) -> bool:
    """Whether a test's difference is shown: its p (Holm's for a Holm-corrected test) below ALPHA."""
    return (test.p if test.primary else test.adjusted) < ALPHA


def judged(test: Test) -> str:
    """'Welch p = 0.0002' for the primary, 'Holm p = 0.020' for the others."""
    return f"Welch {p_text(test.p)}" if test.primary else f"Holm {p_text(test.adjusted)}"


def numbers(test: Test) -> str:
    """'−0.242 [−0.338, −0.149], Holm p = 0.020': the difference, its bootstrap interval and the p it is judged by."""
    return f"{test.text.replace('-', '−')}, {judged(test)}"


def untested_words(tests: list[Test]) -> str | None:
    """Why a question's tests were not run ('withdrawn: its runs ran mixed code versions', 'not run yet: fewer than 2
    runs per arm'), or None when all of them were."""
    if any(t.mixed for t in tests):
        return "**withdrawn**: its runs ran mixed code versions"
    if any(not t.testable for t in tests):
        return "**not run yet**: fewer than 2 runs per arm"
    return None


def direction(test: Test, worse: str, better: str) -> str:
    """`worse` or `better` by the sign of a shown difference, 'not shown' otherwise."""
    return (worse if test.difference < 0 else better) if shown(test) else "not shown"


def verdict_rows(runs: list[dict[str, Any]], tests: list[Test] | None = None) -> list[tuple[str, str, str]]:
    """(question, verdict, numbers) per question of the protocol, from the grid's runs and their tests
    (curriculum_test_rows of them, computed here when not given)."""
    tests = {(t.a, t.b, t.key): t for t in (curriculum_test_rows(runs) if tests is None else tests)}
    auc, success, time = "auc_coverage", "held_out_success", "episodes_to_90"
    primary = tests[("cmcl", "maddpg", auc)]
    per, acl = tests[("cmcl", "per", auc)], tests[("cmcl", "acl", auc)]
    acl_maddpg, per_maddpg = tests[("acl", "maddpg", auc)], tests[("per", "maddpg", auc)]
    ends, sooner = tests[("cmcl", "maddpg", success)], tests[("cmcl", "maddpg", time)]
    information, order = tests[("cmcl", "cmcl_permuted", auc)], tests[("cmcl", "cmcl_anti", auc)]
    rows = []

    def row(question: str, needs: list[Test], verdict: Any, text: Any) -> None:
        why = untested_words(needs)
        rows.append((question, why, "") if why else (question, f"**{verdict()}**", text()))

    def spread(arm: str) -> float:
        return float(np.std([r[auc] for r in runs if r.get("arm") == arm], ddof=1))

    row("**Primary:** does CMCL learn sparse navigation sooner than MADDPG (area under the training coverage curve)?",
        [primary],
        lambda: direction(primary, "not reproduced: CMCL learns later", "reproduced: CMCL learns sooner"),
        lambda: f"{numbers(primary)}. With the observed standard deviations (CMCL {spread('cmcl'):.3f}, MADDPG "
                f"{spread('maddpg'):.3f}) the smallest difference this test detects with 80% power is "
                f"{primary.detectable:.3f}.")
    row("The paper's Fig. 8b: CMCL ahead of PER-MADDPG and ACL", [per, acl, acl_maddpg, per_maddpg],
        lambda: f"against PER-MADDPG {fig8b(per)}; against ACL {fig8b(acl)}",
        lambda: f"{numbers(per)}; {numbers(acl)}. ACL − MADDPG {signed(acl_maddpg.difference)} ({judged(acl_maddpg)}), "
                f"PER-MADDPG − MADDPG {signed(per_maddpg.difference)} ({judged(per_maddpg)}).")
    row("Does CMCL end better (held-out success) or reach MA 0.9 sooner?", [ends, sooner],
        lambda: f"held-out success {direction(ends, 'worse', 'better')}; MA 0.9 {reached(runs, sooner)}",
        lambda: f"success {numbers(ends)}; Kaplan–Meier medians {km_text(times(runs, 'cmcl', time))} against "
                f"{km_text(times(runs, 'maddpg', time))} episodes, log-rank {judged(sooner)}"
                + ("; a median written ≥ M is a lower bound: half the runs got there, M the last of them"
                   if any(kaplan_meier(times(runs, a, time))[2] for a in ("cmcl", "maddpg")) else "") + ".")
    row("Does the curriculum's *information* help (CMCL against the permuted control, same ESS)?", [information],
        lambda: direction(information, "no: it hurts", "yes: it helps"), lambda: numbers(information) + ".")
    row("Does the easy-to-hard *direction* help (CMCL against the anti-curriculum)?", [order],
        lambda: direction(order, "no: it hurts", "yes: it helps"), lambda: numbers(order) + ".")
    return rows


def fig8b(test: Test) -> str:
    """The paper's claim that CMCL is ahead of another arm: 'reproduced', 'not reproduced (behind)' or 'not shown'."""
    return direction(test, "not reproduced (behind)", "reproduced")


def reached(runs: list[dict[str, Any]], test: Test) -> str:
    """A shown log-rank test in words by the Kaplan-Meier medians of its arms ('later', 'sooner'; a median not
    reached counts as the latest), 'not shown' otherwise."""
    if not shown(test):
        return "not shown sooner or later"
    a, b = (kaplan_meier(times(runs, arm, test.key))[0] for arm in (test.a, test.b))
    return "later" if a is None or (b is not None and a > b) else "sooner"


def times(runs: list[dict[str, Any]], arm: str, key: str) -> list[float | None]:
    """One arm's times to threshold (None where a run never got there)."""
    return [r[key] for r in runs if r.get("arm") == arm]


def verdict_table(runs: list[dict[str, Any]]) -> str:
    """The verdict rows as a markdown table, with the code the tests ran ('no runs yet' without runs)."""
    if not runs:
        return NO_RUNS
    tests = curriculum_test_rows(runs)
    code = tests[0].code
    lines = [f"Verdicts by the protocol above, drawn from the tests (code: {code}):", "",
             "| question | verdict | numbers |", "| --- | --- | --- |"]
    return "\n".join(lines + [f"| {q} | {v} | {n} |" for q, v, n in verdict_rows(runs, tests)])


# a settings grid's comparison (a, b, measure) -> (its question, the verdict when a is shown below b, when above)
SETTING_QUESTIONS = {
    ("cmcl_stride_x2", "cmcl", "auc_coverage"): ("Does a shorter exclusion phase (λ stride ×2) help CMCL?",
                                                 "no: it hurts", "yes: it helps"),
    ("cmcl_stride_half", "cmcl", "auc_coverage"): ("Does a longer one (λ stride ×½) hold CMCL back further?",
                                                   "yes: it holds CMCL back", "no: it helps"),
    ("cmcl_stride_x2", "maddpg", "auc_coverage"): ("Does the shorter exclusion phase close the gap to MADDPG?",
                                                   "no: still behind MADDPG", "yes: ahead of MADDPG"),
    ("cmcl_eta1", "cmcl", "auc_coverage"): ("Does a larger curiosity weight (η = 1) help CMCL on the harder task?",
                                            "no: it hurts", "yes: it helps"),
    ("cmcl_eta1", "maddpg", "auc_coverage"): ("Does it close the gap to MADDPG?", "no: still behind MADDPG",
                                              "yes: ahead of MADDPG"),
}


def setting_verdict_table(runs: list[dict[str, Any]], grid_name: str) -> str:
    """A settings grid's verdicts (its runs with the harder task's MADDPG and CMCL runs beside them, as
    lab.report.report.setting_runs gives them): one row per comparison of its Holm family, with the difference,
    its interval, Welch's and Holm's p and the smallest difference the test detects at the family's level."""
    arms, comparisons = SETTING_TABLES[grid_name]
    if not any(r.get("grid") == grid_name for r in runs):
        return NO_RUNS
    tests = curriculum_test_rows(runs, comparisons)
    lines = ["Verdicts by the protocol above, drawn from the tests (Holm-corrected together, no primary):", "",
             "| question | code | verdict | numbers |", "| --- | --- | --- | --- |"]
    for t in tests:
        question, worse, better = SETTING_QUESTIONS[(t.a, t.b, t.key)]
        why = untested_words([t])
        verdict, text = (why, "") if why else (
            f"**{direction(t, worse, better)}**",
            f"{numbers(t)} (Welch {p_text(t.p)}); the smallest difference this test detects with 80% power at the "
            f"family's α/{len(tests)} = {t.level:.3f} is {t.detectable:.3f}.")
        lines.append(f"| {question} | {t.code} | {verdict} | {text} |")
    return "\n".join(lines)

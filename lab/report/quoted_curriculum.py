"""The quoted numbers of the curriculum grids (lab.report.quoted): the blocks headline (README.md and
docs/LEARNING.md: the primary comparison of each curriculum grid), lambdawait (README.md: what `cov` does while
λ < 0.5, from the curriculum grid) and learningcurriculum (docs/LEARNING.md: times to MA 0.9 of the curriculum,
curriculum_hard and curriculum_stride grids). Reads only those grids' summaries, as quoted_blocks passes them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from experiments.labels import ARM_LABEL
from experiments.measures import WINDOW
from lab.report.curriculum_tables import (
    ALPHA,
    SETTING_TABLES,
    Test,
    curriculum_test_rows,
    first_quarter,
    last_excluding_episode,
)
from lab.report.quoted_words import NO_RUNS, joined, km_text, p_text, seeds_text, untested, verdict
from lab.report.stats import TIMES, kaplan_meier

# the curriculum grids of the headline, in its order: grid -> where (the task as a sentence names it)
HEADLINE_TASKS = {"curriculum": "at N = 4", "curriculum_tag": "on predator-prey",
                  "curriculum_hard": "on the harder task"}
# the section of lab/RESULTS.md that holds a grid's tables and verdicts
SECTION = {"curriculum": 'lab/RESULTS.md, "Curriculum grid"',
           "curriculum_hard": 'lab/RESULTS.md, "The curriculum grid on the harder task"',
           "curriculum_stride": 'lab/RESULTS.md, "The λ schedule on the harder task"',
           "curriculum_tag": 'lab/RESULTS.md, "The curriculum grid on predator-prey"'}


def headline(grids: dict[str, list[dict[str, Any]]]) -> str:
    """The primary comparison of each curriculum grid (CMCL − MADDPG in the area under the training curve, the
    protocol of lab/RESULTS.md) as one sentence; a grid whose primary ran mixed code is withdrawn."""
    primaries = {g: curriculum_test_rows(grids[g])[0] for g in HEADLINE_TASKS if grids.get(g)}
    if not primaries:
        return NO_RUNS
    stood = {g: t for g, t in primaries.items() if t.testable}
    ahead = [HEADLINE_TASKS[g] for g, t in stood.items() if t.p < ALPHA and t.difference > 0]
    if stood:
        lead = (f"CMCL beats uniform replay (MADDPG) {joined(ahead)}" if ahead else
                "CMCL does not beat uniform replay (MADDPG) in any comparison that stands")
        text = (f"{lead}: in the area under its training curve over {seeds_text(list(stood.values()))}, CMCL "
                + joined([verdict(t, HEADLINE_TASKS[g]) for g, t in stood.items()]))
    else:
        text = "No comparison of CMCL with uniform replay (MADDPG) in the area under the training curve stands yet"
    return text + "".join(f"; {HEADLINE_TASKS[g]} the comparison is {untested(t)}"
                          for g, t in primaries.items() if not t.testable) + "."


def coverage_at(runs: list[dict[str, Any]], episode: float) -> float:
    """The mean over runs of the training coverage curve (WINDOW-episode windows) at `episode`."""
    n = min(len(r["curves"]["coverage"]) for r in runs)
    curve = np.mean([r["curves"]["coverage"][:n] for r in runs], axis=0)
    return float(np.interp(episode, (np.arange(n) + 1) * WINDOW, curve))


def lambda_wait(curriculum: list[dict[str, Any]]) -> str:
    """README.md's sentence on what `cov` does while λ < 0.5, from the curriculum grid (N = 4)."""
    from lab.report.curriculum_figure import episode_lambda_reaches

    cmcl, maddpg = ([r for r in curriculum if r.get("arm") == arm] for arm in ("cmcl", "maddpg"))
    half = episode_lambda_reaches(cmcl, 0.5)
    if not cmcl or not maddpg or half is None:
        return ("While λ < 0.5 the paper's curriculum can exclude the reward-bearing rows from its samples "
                "(lab/RESULTS.md; the curriculum grid has no runs here yet to say how far).")
    waits = coverage_at(cmcl, half)
    sampled, buffer = (np.mean([first_quarter(r, k) for r in cmcl]) for k in ("reward_rows_sampled",
                                                                              "reward_rows_buffer"))
    return (f"While λ < 0.5 the paper's curriculum samples those rows far less often than the buffer holds them, and "
            f"`cov` waits near {waits:.1f}; that is expected of CMCL (lab/RESULTS.md; in the curriculum grid, over "
            f"{len(cmcl)} seeds, reward-bearing rows are {sampled:.3f} of CMCL's sampled rows in the first quarter "
            f"against {buffer:.3f} of its buffer, and its mean training coverage is {waits:.2f} where λ reaches 0.5, "
            f"at episode {half:,.0f}, where MADDPG's is {coverage_at(maddpg, half):.2f}).")


def times_clause(runs: list[dict[str, Any]], arms: tuple[str, ...]) -> str:
    """'MADDPG 10,949 (10/10), PER-MADDPG 12,051 (10/10), ...': KM medians of episodes to MA 0.9 per arm."""
    return ", ".join(f"{ARM_LABEL[a]} {km_text([r['episodes_to_90'] for r in runs if r.get('arm') == a])}"
                     for a in arms if any(r.get("arm") == a for r in runs))


def time_test(tests: list[Test], where: str) -> str:
    """The protocol's log-rank test of CMCL against MADDPG in words; where: the section of lab/RESULTS.md."""
    t = next(t for t in tests if t.key in TIMES)
    if not t.testable:
        return "its tests are " + untested(t, where)
    return f"CMCL against MADDPG, log-rank {p_text(t.p)} (Holm {p_text(t.adjusted)}; {where})"


def curriculum_times(curriculum: list[dict[str, Any]], hard: list[dict[str, Any]],
                     stride: list[dict[str, Any]]) -> str:
    """docs/LEARNING.md's paragraph on the curriculum grids' times to MA 0.9 (KM medians) and their tests."""
    main = ("maddpg", "per", "acl", "cmcl")
    out = []
    if curriculum:
        tests = curriculum_test_rows(curriculum)
        out.append(f"Time to a training moving average of 0.9, as Kaplan–Meier medians over {seeds_text(tests)} (runs "
                   f"that got there): at N = 4 {times_clause(curriculum, main)} episodes; "
                   f"{time_test(tests, SECTION['curriculum'])}.")
    if hard:
        tests = curriculum_test_rows(hard)
        out.append(f"On the harder task (cover radius 0.075, {seeds_text(tests)}): {times_clause(hard, main)}; "
                   f"{time_test(tests, SECTION['curriculum_hard'])}.")
    arms, comparisons = SETTING_TABLES["curriculum_stride"]
    if all(any(r.get("arm") == a for r in stride) for a in arms):
        tests = curriculum_test_rows(stride, comparisons)
        last = {a: np.mean([last_excluding_episode(r) for r in stride if r.get("arm") == a]) for a in arms[1:]}
        median = {a: km_text([r["episodes_to_90"] for r in stride if r.get("arm") == a]) for a in arms[1:]}
        said = [f"{ARM_LABEL[t.a]} − {ARM_LABEL[t.b]} {verdict(t)}" for t in tests if t.testable]
        said += [f"{ARM_LABEL[t.a]} − {ARM_LABEL[t.b]} is {untested(t)}" for t in tests if not t.testable
                 and not t.mixed]
        mixed = any(t.mixed for t in tests)
        out.append(f"CMCL's Kaplan–Meier median to MA 0.9 at twice the default λ stride (the last progress row with "
                   f"λ < 0.5 at episode {last['cmcl_stride_x2']:,.0f} on average, against {last['cmcl']:,.0f} at the "
                   f"default): {median['cmcl_stride_x2']}; at half the stride ({last['cmcl_stride_half']:,.0f}): "
                   f"{median['cmcl_stride_half']}"
                   + "".join(f"; {x}" for x in said)
                   + (f"; {'its other' if said else 'its'} tests are withdrawn until its runs and the harder task's "
                      "runs they compare against are at one commit" if mixed else "")
                   + f" ({'mixed code versions; ' if mixed else ''}{SECTION['curriculum_stride']}).")
    if any(kaplan_meier([r["episodes_to_90"] for r in rs if r.get("arm") == a])[2]
           for rs in (curriculum, hard, stride) for a in {r.get("arm") for r in rs}):
        out.append("A median written \"≥ M\" is a lower bound: exactly half the runs got there, M the last of them.")
    return " ".join(out) or NO_RUNS

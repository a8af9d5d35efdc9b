"""The numbers README.md and docs/LEARNING.md quote from the grids (issue 35), as the sentences and tables that hold
them, drawn from the committed summaries by the statistics of docs/RESULTS.md's tables (experiments.stats, tables,
curriculum_tables). `python -m experiments report --update README.md` and `--update docs/LEARNING.md` write them into
their marked blocks; tests/test_quoted_numbers.py regenerates both pages and fails on any difference.

Wording follows the tests, not the author: a comparison whose runs ran different code (experiments.provenance) is
quoted as withdrawn, with no number; one at p ≥ α as "not shown"; a Kaplan-Meier median that is only a lower bound
keeps its "≥".

Blocks: headline (README.md and docs/LEARNING.md: the primary comparison of each curriculum grid); lambdawait
(README.md: what `cov` does while λ < 0.5); in docs/LEARNING.md, tts, schedule and ttstag (the time-to-solve grids'
tables), learningcurriculum (times to MA 0.9 of the curriculum grids), learningspread, learningtag and
learningablations (the paper's grids at the old defaults) and refactoring (the service runs after the
one-implementation refactoring, bench/results/time_to_solve_issue8).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from experiments.curriculum_tables import (
    ALPHA,
    SETTING_TABLES,
    Test,
    curriculum_test_rows,
    first_quarter,
    last_excluding_episode,
)
from experiments.labels import ARM_LABEL, LABEL, ORDER
from experiments.measures import WINDOW
from experiments.stats import TIMES, fmt, kaplan_meier, logrank_p, median_text, paired_test, welch_test
from experiments.store import ResultsStore
from experiments.tables import (
    BASELINES,
    FIG13_WIN,
    SOLVE_HEADER,
    SPREAD_TESTS,
    TAG_TESTS,
    against_threshold,
    predators_vs_maddpg_prey,
    solve_cells,
    solve_groups,
    solve_tag_table,
)

# the curriculum grids of the headline, in its order: grid -> where (the task as a sentence names it)
HEADLINE_TASKS = {"curriculum": "at N = 4", "curriculum_tag": "on predator-prey",
                  "curriculum_hard": "on the harder task"}
AREA_NAME = {"auc_coverage": "area under the training coverage curve",
             "auc_predator_win": "area under the predators' training win curve"}
ABLATION_LABEL = {"eta0": "η = 0", "eta1": "η = 1", "k2": "K = 2", "rank": "`rank` normalisation",
                  "max": "`max` normalisation", "stride_x2": "the λ stride ×2", "stride_half": "the λ stride ×0.5",
                  "is_on": "IS correction on", "paper_schedule": "the paper's schedule"}
# the service runs after the one-implementation refactoring (`python -m experiments run algorithms --modes service
# --algorithms cmcl maddpg --seeds 0 1 2 --out bench/results/time_to_solve_issue8`), under the results root
REFACTORING = "time_to_solve_issue8"
# the section of docs/RESULTS.md that holds a grid's tables and verdicts
SECTION = {"curriculum": 'docs/RESULTS.md, "Curriculum grid"',
           "curriculum_hard": 'docs/RESULTS.md, "The curriculum grid on the harder task"',
           "curriculum_stride": 'docs/RESULTS.md, "The λ schedule on the harder task"',
           "curriculum_tag": 'docs/RESULTS.md, "The curriculum grid on predator-prey"'}


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


def headline(grids: dict[str, list[dict[str, Any]]]) -> str:
    """The primary comparison of each curriculum grid (CMCL − MADDPG in the area under the training curve, the
    protocol of docs/RESULTS.md) as one sentence; a grid whose primary ran mixed code is withdrawn."""
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
    from experiments.curriculum_figure import episode_lambda_reaches

    cmcl, maddpg = ([r for r in curriculum if r.get("arm") == arm] for arm in ("cmcl", "maddpg"))
    half = episode_lambda_reaches(cmcl, 0.5)
    if not cmcl or not maddpg or half is None:
        return ("While λ < 0.5 the paper's curriculum can exclude the reward-bearing rows from its samples "
                "(docs/RESULTS.md; the curriculum grid has no runs here yet to say how far).")
    waits = coverage_at(cmcl, half)
    sampled, buffer = (np.mean([first_quarter(r, k) for r in cmcl]) for k in ("reward_rows_sampled",
                                                                              "reward_rows_buffer"))
    return (f"While λ < 0.5 the paper's curriculum samples those rows far less often than the buffer holds them, and "
            f"`cov` waits near {waits:.1f}; that is expected of CMCL (docs/RESULTS.md; in the curriculum grid, over "
            f"{len(cmcl)} seeds, reward-bearing rows are {sampled:.3f} of CMCL's sampled rows in the first quarter "
            f"against {buffer:.3f} of its buffer, and its mean training coverage is {waits:.2f} where λ reaches 0.5, "
            f"at episode {half:,.0f}, where MADDPG's is {coverage_at(maddpg, half):.2f}).")


def times_clause(runs: list[dict[str, Any]], arms: tuple[str, ...]) -> str:
    """'MADDPG 10,949 (10/10), PER-MADDPG 12,051 (10/10), ...': KM medians of episodes to MA 0.9 per arm."""
    return ", ".join(f"{ARM_LABEL[a]} {km_text([r['episodes_to_90'] for r in runs if r.get('arm') == a])}"
                     for a in arms if any(r.get("arm") == a for r in runs))


def time_test(tests: list[Test], where: str) -> str:
    """The protocol's log-rank test of CMCL against MADDPG in words; where: the section of docs/RESULTS.md."""
    t = next(t for t in tests if t.key in TIMES)
    if not t.testable:
        return "its tests are " + untested(t, where)
    return f"CMCL against MADDPG, log-rank {p_text(t.p)} (Holm {t.adjusted:.3f}; {where})"


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
        out.append(f"CMCL at twice the default λ stride (the last progress row with λ < 0.5 at episode "
                   f"{last['cmcl_stride_x2']:,.0f} on average, against {last['cmcl']:,.0f} at the default) reaches MA "
                   f"0.9 at a median of {median['cmcl_stride_x2']}, at half the stride "
                   f"({last['cmcl_stride_half']:,.0f}) {median['cmcl_stride_half']}"
                   + "".join(f"; {x}" for x in said)
                   + (f"; {'its other' if said else 'its'} tests compare against the harder task's runs and are "
                      "withdrawn with them" if mixed else "")
                   + f" ({'mixed code versions; ' if mixed else ''}{SECTION['curriculum_stride']}).")
    if any(kaplan_meier([r["episodes_to_90"] for r in rs if r.get("arm") == a])[2]
           for rs in (curriculum, hard, stride) for a in {r.get("arm") for r in rs}):
        out.append("A median written \"≥ M\" is a lower bound: exactly half the runs got there, M the last of them.")
    return " ".join(out) or NO_RUNS


def spread_summary(spread: list[dict[str, Any]]) -> str:
    """docs/LEARNING.md's table of the spread grid (the paper's budget, old defaults) and what its tests show."""
    by_alg = {a: sorted((r for r in spread if r["algorithm"] == a), key=lambda r: r["seed"]) for a in ORDER}
    seeds = sorted({r["seed"] for r in spread})
    lines = ["| algorithm | seeds | held-out coverage | held-out success | episodes to MA 0.9 (Kaplan–Meier median, "
             "runs that got there) | runs with coverage ≥ 0.9 and success ≥ 0.8 | wall s for 20,000 episodes, seed by "
             "seed (" + ", ".join(str(s) for s in seeds) + ") |", "| --- " * 7 + "|"]
    met_total = 0
    for a, rs in by_alg.items():
        if not rs:
            continue
        missed = [r for r in rs if not (r["held_out_coverage"] >= 0.9 and r["held_out_success"] >= 0.8)]
        met_total += len(rs) - len(missed)
        miss = "; ".join(f"seed {r['seed']}: {r['held_out_coverage']:.3f} / {r['held_out_success']:.2f}"
                         for r in missed)
        walls = {r["seed"]: f"{r['wall_s']:.0f}" for r in rs}
        lines.append(f"| {LABEL[a]} | {len(rs)} | {fmt([r['held_out_coverage'] for r in rs], 3, 'held_out_coverage')} "
                     f"| {fmt([r['held_out_success'] for r in rs], 3, 'held_out_success')} | "
                     f"{km_text([r['episodes_to_90'] for r in rs])} | {len(rs) - len(missed)} of {len(rs)}"
                     + (f" ({miss})" if miss else "") + " | " + ", ".join(walls.get(s, "—") for s in seeds) + " |")
    cmcl = by_alg["cmcl"]
    pvalues, ahead = [], []
    for base in (b for b in BASELINES if len(by_alg[b]) > 1 and len(cmcl) > 1):
        rs = by_alg[base]
        for _, key, _ in SPREAD_TESTS:
            d, _, p = welch_test([r[key] for r in cmcl], [r[key] for r in rs])
            pvalues += [] if np.isnan(p) else [p]
            ahead += [f"{LABEL[base]} ({key})"] if p < ALPHA and d > 0 else []
        times = [r["episodes_to_90"] for r in cmcl], [r["episodes_to_90"] for r in rs]
        pvalues.append(logrank_p(*times, cmcl[0]["budget"]))
    if not pvalues:
        return "\n".join([*lines, "", "No test of CMCL against a baseline yet (fewer than 2 runs per arm)."])
    coverage = [np.mean([r["held_out_coverage"] for r in rs]) for rs in by_alg.values() if rs]
    below = [p for p in pvalues if p < ALPHA]
    tests = (f"{len(pvalues)} tests: Welch on mean reward, area under coverage and held-out success, log-rank on "
             "episodes to MA 0.9")
    shown = (f"no difference between CMCL and a baseline is significant (p ≥ {min(pvalues):.2f} in all {tests})"
             if not below else f"{len(below)} of its {tests} are below {ALPHA} uncorrected")
    solved = "Every algorithm solves" if min(coverage) >= 0.9 else "Not every algorithm solves"
    claims = ("The paper's navigation claims are therefore **not reproduced** here (docs/RESULTS.md)." if not ahead
              else f"CMCL is ahead of {joined(ahead)} uncorrected; docs/RESULTS.md has the verdicts.")
    lines += ["", f"{solved} navigation at this budget (mean held-out coverage {span(coverage, 3)}; {met_total} of "
              f"{len(spread)} runs meet both targets), and {shown}. {claims}"]
    return "\n".join(lines)


def tag_summary(tag: list[dict[str, Any]], curriculum_tag: list[dict[str, Any]]) -> str:
    """docs/LEARNING.md's paragraph on predator-prey: the tag and winrate grids (Figs. 12-13, old defaults) and the
    primary comparison of the curriculum_tag grid."""
    vs_maddpg = predators_vs_maddpg_prey(tag)
    wins = {prey: [r["win_vs_trained_prey"] for r in tag if r["algorithm"] == "cmcl" and r["prey_algorithm"] == prey]
            for prey in ("acl", "per")}
    if any(len(vs_maddpg[a]) < 2 for a in ORDER) or any(len(w) < 2 for w in wins.values()):
        return NO_RUNS + " (fewer than 2 runs in a cell of the tag and winrate grids)"
    cells = {(r["algorithm"], r["prey_algorithm"]) for r in tag}
    counts = [sum((r["algorithm"], r["prey_algorithm"]) == c for r in tag) for c in cells]
    reward = {a: fmt([r["mean_reward_predator"] for r in vs_maddpg[a]], 1, "mean_reward_predator")
              for a in ORDER if vs_maddpg[a]}
    family = len(BASELINES) * len(TAG_TESTS)  # the tests of its table, Bonferroni-corrected together
    tests = {b: welch_test(*([r["mean_reward_predator"] for r in vs_maddpg[a]] for a in ("cmcl", b)))
             for b in BASELINES}
    closest = min(tests, key=lambda b: tests[b][2])
    mann_whitney = stats.mannwhitneyu(*([r["mean_reward_predator"] for r in vs_maddpg[a]] for a in ("cmcl", closest)))
    said = [f"minus {LABEL[b]} {signed(d, 1)} (Welch {p_text(p)}"
            + (f"; Mann–Whitney {p_text(mann_whitney.pvalue)}" if b == closest else "") + ")"
            for b, (d, _, p) in tests.items()]
    corrected = {b: min(1.0, p * family) for b, (_, _, p) in tests.items()}
    shown = [b for b in BASELINES if corrected[b] < ALPHA]
    text = (f"Predator-prey, same budget and settings, {span(counts, 0)} seeds per cell (`--grid tag winrate`): CMCL "
            f"predators earn {reward['cmcl']} per episode against MADDPG prey, against "
            + joined([f"{reward[b]} ({LABEL[b]})" for b in BASELINES]) + f". CMCL {joined(said)}; corrected for the "
            f"{family} tests of its table (Bonferroni) the smallest is {min(corrected.values()):.3f}, so "
            + (f"a difference is shown against {joined([LABEL[b] for b in shown])}. " if shown else
               "no difference is shown. "))
    maddpg = [r["win_vs_trained_prey"] for r in vs_maddpg["maddpg"]]
    text += (f"CMCL predators win {fmt(wins['acl'], 3, 'win_vs_trained_prey')} of held-out rounds against ACL prey and "
             f"{fmt(wins['per'], 3, 'win_vs_trained_prey')} against PER-MADDPG prey (bootstrap 95% intervals), but "
             f"MADDPG predators win {np.mean(maddpg):.3f} against MADDPG prey too. ")
    uncorrected_only = [LABEL[b] for b, (d, _, p) in tests.items() if d > 0 and p < ALPHA <= corrected[b]]
    fig12 = "reproduced" if len(shown) == len(BASELINES) and all(tests[b][0] > 0 for b in BASELINES) else \
        "not reproduced" + (f", and against {joined(uncorrected_only)} not shown" if uncorrected_only else "")
    above, p = against_threshold(wins["per"])
    fig13 = "shown" if above > 0 and p < ALPHA else "not shown"
    text += (f"Verdicts (docs/RESULTS.md): Fig. 12 {fig12}; Fig. 13's \"above {FIG13_WIN}\" {fig13} (mean − "
             f"{FIG13_WIN} = {signed(above)}, {p_text(p)}). These runs are at the old defaults (`max` difficulty, "
             "α = 0.6).")
    if curriculum_tag:
        t = curriculum_test_rows(curriculum_tag)[0]
        arms = [sum(r["arm"] == a for r in curriculum_tag) for a in {r["arm"] for r in curriculum_tag}]
        said = (f"in the {AREA_NAME[t.key]} against MADDPG, CMCL {verdict(t)}" if t.testable else
                f"its primary comparison (CMCL − MADDPG) is {untested(t)}")
        text += (f" Predator-prey was re-run at the issue-21 defaults (grid `curriculum_tag`: {len(arms)} arms × "
                 f"{span(arms, 0)} seeds, {len(curriculum_tag)} runs, MADDPG prey; {SECTION['curriculum_tag']}): "
                 f"{said}.")
    return text


def ablation_summary(ablations: list[dict[str, Any]], reference: list[dict[str, Any]],
                     acl: list[dict[str, Any]]) -> str:
    """docs/LEARNING.md's sentences on the ablations at the full budget: the paired tests of each variant against the
    unchanged CMCL runs of the same seeds, and whether CMCL at η = 0 trains as ACL."""
    budget = max((r["budget"] for r in reference), default=None)
    variants: dict[str, list[dict[str, Any]]] = {}
    for r in ablations:
        if r["budget"] == budget:
            variants.setdefault(r["ablation"], []).append(r)
    ref = {r["seed"]: r for r in reference if r["budget"] == budget}
    tests = []
    for name, rs in variants.items():
        for key in ("auc_coverage", "held_out_success"):
            m, h, p, n = paired_test({r["seed"]: r[key] for r in rs}, {s: r[key] for s, r in ref.items()})
            tests.append((name, key, m, h, p))
    tests = [t for t in tests if not np.isnan(t[4])]
    if not tests:
        return NO_RUNS + " (no variant with 2 seeds paired with the unchanged CMCL runs)"
    inside = sum(m - h <= 0 <= m + h for _, _, m, h, _ in tests)
    name, key, m, _, p = min(tests, key=lambda t: t[4])
    seeds = [len(rs) for rs in variants.values()]
    labels = list(ABLATION_LABEL)
    order = sorted(variants, key=lambda v: labels.index(v) if v in labels else len(labels))
    measure = "area under coverage" if key == "auc_coverage" else "held-out success"
    text = (f"Ablations of CMCL, same budget, {span(seeds, 0)} seeds each (`python -m experiments run ablations "
            f"--seeds 0 1 2 3 4`): {joined([ABLATION_LABEL.get(v, v) for v in order])} against the unchanged CMCL "
            "runs of the same seeds (paired t on area under coverage and held-out success): "
            f"{'all' if inside == len(tests) else f'{inside} of'} {len(tests)} 95% intervals contain 0; the smallest "
            f"p is {ABLATION_LABEL.get(name, name)}'s {measure} ({signed(m)}, {p_text(p)}), "
            + ("not shown at 5%." if p >= ALPHA else f"below 0.05 uncorrected, one of {len(tests)} tests."))
    if "eta0" in variants:
        by_seed = {r["seed"]: r for r in acl}
        same = [r["seed"] for r in variants["eta0"] if r["seed"] in by_seed and all(
            r[k] == by_seed[r["seed"]][k] for k in ("curves", "updates", *[k for k in r if k.startswith("held_out")]))]
        text += (f" CMCL at η = 0 trains exactly as ACL, to the bit, on {len(same)} of {len(variants['eta0'])} seeds "
                 "(the same curves, held-out figures and updates).")
    return text + " Table and figure: docs/RESULTS.md \"Ablations\"."


def reached_text(rs: list[dict[str, Any]]) -> str:
    """'2 of 3 seeds (9,301 and 10,436 episodes, 149 and 166 s; seed 0 ended at a moving average of 0.76, held-out
    coverage 0.77)' for the runs of one cell of a time-to-solve grid."""
    got = sorted((r for r in rs if r["episodes_to_90"] is not None), key=lambda r: r["episodes_to_90"])
    missed = sorted((r for r in rs if r["episodes_to_90"] is None), key=lambda r: r["seed"])
    parts = []
    if len(got) > 2:
        parts.append(f"{got[0]['episodes_to_90']:,}–{got[-1]['episodes_to_90']:,} episodes, "
                     f"{span([r['seconds_to_90'] for r in got], 0)} s")
    elif got:
        parts.append(joined([f"{r['episodes_to_90']:,}" for r in got]) + " episodes, "
                     + joined([f"{r['seconds_to_90']:.0f}" for r in got]) + " s")
    if got and not missed:
        parts.append(f"held-out coverage {span([r['held_out_coverage'] for r in got], 2)}")
    parts += [f"seed {r['seed']} ended at a moving average of {r['final_ma_coverage']:.2f}, held-out coverage "
              f"{r['held_out_coverage']:.2f}" for r in missed]
    return f"{len(got)} of {len(rs)} seeds ({'; '.join(parts)})"


def refactoring_summary(after: list[dict[str, Any]], before: list[dict[str, Any]]) -> str:
    """docs/LEARNING.md's sentence on the service runs after the one-implementation refactoring, against the
    algorithms grid's service runs of the same algorithms and seeds."""
    algorithms = [a for a in ORDER if any(r["algorithm"] == a for r in after)]
    cells = {a: [r for r in after if r["algorithm"] == a] for a in algorithms}
    earlier = {a: [r for r in before if r.get("grid") == "algorithms" and r.get("mode") == "service"
                   and r["algorithm"] == a and r["seed"] in {x["seed"] for x in cells[a]}] for a in algorithms}
    text = ", ".join(f"service {LABEL[a]} reached MA 0.9 on {reached_text(cells[a])}" for a in algorithms)
    counts = {a: (sum(r["episodes_to_90"] is not None for r in rs), len(rs)) for a, rs in earlier.items()}
    now = {a: (sum(r["episodes_to_90"] is not None for r in rs), len(rs)) for a, rs in cells.items()}
    return (text[0].upper() + text[1:] + ". " + ("The same counts as before it" if counts == now else
                                                  "Before it (the algorithms grid's service runs)")
            + " (" + ", ".join(f"{LABEL[a]} {k} of {n}" for a, (k, n) in counts.items()) + ").")


def solve_tables(runs: list[dict[str, Any]]) -> dict[str, str]:
    """docs/LEARNING.md's tables of the time-to-solve grids: tts (the algorithms grid per mode and algorithm), schedule
    (the schedule grid per update_every and batch, its MADDPG cell at the default schedule completed by the algorithms
    grid's inline MADDPG runs of the seeds it lacks: the same configuration) and ttstag (predator-prey, with what its
    ranges show)."""
    algorithms = [r for r in runs if r.get("grid") == "algorithms"]
    schedule = [r for r in runs if r.get("grid") == "schedule"]
    have = {(r["algorithm"], r["update_every"], r["batch_size"], r["seed"]) for r in schedule}
    schedule += [r for r in algorithms if r.get("mode", "inline") == "inline"
                 and (r["algorithm"], r["update_every"], r["batch_size"], r["seed"]) not in have
                 and any((r["algorithm"], r["update_every"], r["batch_size"]) == h[:3] for h in have)]
    out = {}
    for name, rs, fields in (("tts", algorithms, ("mode", "algorithm")),
                             ("schedule", schedule, ("algorithm", "update_every", "batch_size"))):
        groups = solve_groups(rs, fields)
        header = " | ".join("batch" if f == "batch_size" else f for f in fields)
        rows = [f"| {' | '.join(str(k) for k in key)} | {solve_cells(groups[key])} |" for key in sorted(groups)]
        out[name] = "\n".join([f"| {header} | {SOLVE_HEADER}", "| --- " * (len(fields) + 8) + "|", *rows]) \
            if rows else NO_RUNS
    tag = [r for r in runs if r.get("task") == "tag"]
    out["ttstag"] = NO_RUNS
    if tag:
        by_alg = {a: [r for r in tag if r["algorithm"] == a] for a in sorted({r["algorithm"] for r in tag})}
        trained = {a: [r["win_vs_trained_prey"] for r in rs] for a, rs in by_alg.items()}
        random_prey, random = ([r[k] for r in tag] for k in ("win_vs_random_prey", "random_vs_random"))
        overlap = all(min(max(x), max(y)) >= max(min(x), min(y)) for x in trained.values() for y in trained.values())
        seeds = span([len(rs) for rs in by_alg.values()], 0)
        out["ttstag"] = solve_tag_table(tag) + "\n\n" + (
            f"Trained predators beat random prey {'clearly ' if min(random_prey) > max(random) else ''}with every "
            f"algorithm and seed ({span(random_prey, 2)} against {span(random, 2)} for random predators), and beat the "
            f"MADDPG prey trained beside them in {span([w for ws in trained.values() for w in ws], 2)} of rounds. "
            + (f"The ranges of the {len(by_alg)} algorithms overlap over {seeds} seeds: an order between them is not "
               "shown." if overlap else f"Over {seeds} seeds no test is run: an order between them is not shown."))
    return out


def quoted_blocks(where: dict[str, Path], root: Path) -> dict[str, str]:
    """Every block of this module: {marker name: markdown}. where: grid -> its results folder (report.folders);
    root: the results root, which holds REFACTORING."""
    grids = {g: ResultsStore(where[g]).load() for g in ("curriculum", "curriculum_hard", "curriculum_tag",
                                                        "curriculum_stride")}
    paper = ResultsStore(where["spread"]).load()
    spread = [r for r in paper if r.get("grid", "spread") == "spread" and r["task"] == "spread"]
    out = {"headline": headline(grids), "lambdawait": lambda_wait(grids["curriculum"]),
           "learningcurriculum": curriculum_times(grids["curriculum"], grids["curriculum_hard"],
                                                  [r for r in grids["curriculum_hard"]
                                                   if r.get("arm") in SETTING_TABLES["curriculum_stride"][0]]
                                                  + grids["curriculum_stride"])}
    out["learningspread"] = spread_summary(spread) if spread else NO_RUNS
    tag = [r for r in paper if r["task"] == "tag"]
    out["learningtag"] = tag_summary(tag, grids["curriculum_tag"]) if tag else NO_RUNS
    ablations = [r for r in paper if r.get("grid") == "ablations"]
    out["learningablations"] = ablation_summary(
        ablations, [r for r in spread if r["algorithm"] == "cmcl"], [r for r in spread if r["algorithm"] == "acl"]) \
        if ablations else NO_RUNS
    solve = ResultsStore(where["schedule"]).load()
    out.update(solve_tables(solve))
    after = ResultsStore(root / REFACTORING).load()
    out["refactoring"] = refactoring_summary(after, solve) if after else NO_RUNS
    return out

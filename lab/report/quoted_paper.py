"""The quoted numbers of the paper's grids at the old defaults (lab.report.quoted), the blocks of docs/LEARNING.md:
learningspread (the spread grid's table and what its tests show), learningtag (the tag and winrate grids, Figs.
12-13, with the primary comparison of the curriculum_tag grid) and learningablations (the ablations against the
unchanged CMCL runs of the spread grid). Reads only those grids' summaries, as quoted_blocks passes them.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy import stats

from experiments.labels import LABEL, ORDER
from lab.report.curriculum_tables import ALPHA, curriculum_test_rows
from lab.report.quoted_curriculum import SECTION
from lab.report.quoted_words import NO_RUNS, joined, km_text, p_text, signed, span, untested, verdict
from lab.report.stats import fmt, logrank_p, paired_test, welch_test
from lab.report.tables import (
    BASELINES,
    FIG13_WIN,
    SPREAD_TESTS,
    TAG_TESTS,
    against_threshold,
    predators_vs_maddpg_prey,
)

AREA_NAME = {"auc_coverage": "area under the training coverage curve",
             "auc_predator_win": "area under the predators' training win curve"}
ABLATION_LABEL = {"eta0": "η = 0", "eta1": "η = 1", "k2": "K = 2", "rank": "`rank` normalisation",
                  "max": "`max` normalisation", "stride_x2": "the λ stride ×2", "stride_half": "the λ stride ×0.5",
                  "is_on": "IS correction on", "paper_schedule": "the paper's schedule"}


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
    claims = ("The paper's navigation claims are therefore **not reproduced** here (lab/RESULTS.md)." if not ahead
              else f"CMCL is ahead of {joined(ahead)} uncorrected; lab/RESULTS.md has the verdicts.")
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
    text += (f"Verdicts (lab/RESULTS.md): Fig. 12 {fig12}; Fig. 13's \"above {FIG13_WIN}\" {fig13} (mean − "
             f"{FIG13_WIN} = {signed(above)}, {p_text(p)}). These runs are at the old defaults (`max` difficulty, "
             "α = 0.6).")
    if curriculum_tag:
        t = curriculum_test_rows(curriculum_tag)[0]
        arms = [sum(r["arm"] == a for r in curriculum_tag) for a in {r["arm"] for r in curriculum_tag}]
        said = (f"in the {AREA_NAME[t.key]} against MADDPG, CMCL {verdict(t)}" if t.testable else
                f"its primary comparison (CMCL − MADDPG) is {untested(t)}")
        text += (" Predator-prey was re-run at the rank-difficulty defaults (grid `curriculum_tag`: "
                 f"{len(arms)} arms × {span(arms, 0)} seeds, {len(curriculum_tag)} runs, MADDPG prey; "
                 f"{SECTION['curriculum_tag']}): {said}.")
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
    return text + " Table and figure: lab/RESULTS.md \"Ablations\"."

"""The sparse tasks' tables (docs/SPARSE_TASKS.md, its calibration, screen and confirmation protocols): the
calibration per run and its verdict per task, the screen per candidate and its choice (experiments.sparse_arms), the
confirmation per arm and its tests (one-sided Mann-Whitney U, Holm across every comparison of every task).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy import stats

from cmcl.config import load_config
from experiments.grids import SPARSE_TASKS
from experiments.provenance import cell_versions
from experiments.run_spec import ROOT
from experiments.sparse_arms import (
    CALIBRATION_SEEDS,
    SCREEN_ROUNDS,
    SPARSE_CONFIRM_SEEDS,
    SPARSE_SCREEN,
    SPARSE_SCREEN_TASKS,
    ScreenRound,
    SparseNotReady,
    config_of,
    is_curriculum,
    sparse_choice,
)
from lab.report.stats import holm

SUITE_LEVEL = 0.2  # a task stays in the suite while uniform MADDPG's mean held-out success is below it
GOAL_SUCCESS, ALPHA = 0.8, 0.05  # the goal's held-out success and the family-wise level


def _code(run: dict[str, Any]) -> str:
    return (run.get("provenance") or {}).get("commit", "?")[:7]


def _number(value: Any, pattern: str = "{:,.0f}") -> str:
    return "–" if value is None else pattern.format(value)


def calibration_table(runs: list[dict[str, Any]]) -> str:
    """One row per calibration run, task by task (SPARSE_TASKS' order), MADDPG first, by seed: the code, the episodes
    and updates the budget held, the machine's mean 1-minute load over the run, held-out success (and coverage on the
    navigation tasks) and the random policy's on the same held-out episodes."""
    lines = ["| task | algorithm | seed | code | episodes in the budget | updates | load (mean) | held-out success | "
             "random policy |", "| --- " * 9 + "|"]
    order = list(SPARSE_TASKS)
    for r in sorted(runs, key=lambda r: (order.index(r["env"]), r["algorithm"] != "maddpg", r["algorithm"],
                                         r["seed"])):
        coverage = f" (coverage {r['held_out_coverage']:.3f})" if "held_out_coverage" in r else ""
        lines.append(f"| {r['env']} | {r['algorithm']} | {r['seed']} | {_code(r)} | {_number(r['episodes'])} | "
                     f"{_number(r.get('updates'))} | {_number((r.get('provenance') or {}).get('load_mean'), '{:.1f}')}"
                     f" | {r['held_out_success']:.3f}{coverage} | {r['random_success']:.3f} |")
    return "\n".join(lines)


def calibration_verdicts(runs: list[dict[str, Any]], tasks: tuple[str, ...] = tuple(SPARSE_TASKS)) -> str:
    """Per task of `tasks` with a MADDPG run: its mean held-out success over the seeds so far and whether the task
    stays in the suite (< SUITE_LEVEL), said as final only once the three calibration seeds are in."""
    out = []
    for task in tasks:
        rs = sorted((r for r in runs if r["env"] == task and r["algorithm"] == "maddpg"), key=lambda r: r["seed"])
        if not rs:
            out.append(f"- {task}: not calibrated yet.")
            continue
        mean = float(np.mean([r["held_out_success"] for r in rs]))
        seeds = ", ".join(str(r["seed"]) for r in rs)
        stays = "stays in the suite" if mean < SUITE_LEVEL else "leaves the suite"
        planned = len(CALIBRATION_SEEDS)
        so_far = "" if len(rs) >= planned else f" (so far: {len(rs)} of {planned} seeds)"
        out.append(f"- {task}: uniform MADDPG's mean held-out success {mean:.3f} over seeds {seeds}: {stays} "
                   f"(< {SUITE_LEVEL} to stay){so_far}.")
    return "\n".join(out)


def _stages(task: str, candidate: str) -> int:
    """The number of stages of a curriculum candidate's schedule on `task` (0 for curiosity)."""
    if not is_curriculum(candidate):
        return 0
    config = load_config(ROOT / "configs" / config_of(task, candidate), list(SPARSE_SCREEN[candidate][1]))
    return len(config.task_curriculum.stages)


def screen_table(runs: list[dict[str, Any]]) -> str:
    """Per task, round (SCREEN_ROUNDS) and candidate, over the screen's runs so far: the seeds, the code, held-out
    success per seed and its mean, the training success over the last 10 % of episodes (mean), the last stage each
    seed reached of the schedule's (curricula), curiosity's mean reward over the first tenth of updates, episodes
    (mean)."""
    lines = ["| task | candidate | seeds | code | held-out success per seed | mean | training success, last tenth | "
             "stage reached per seed | intrinsic reward, first tenth | episodes (mean) |", "| --- " * 10 + "|"]
    for task, candidate, this in ((t, c, r) for t, rounds in SCREEN_ROUNDS.items() for r in rounds
                                  for c in r.candidates):
        rs = sorted((r for r in runs if r.get("env") == task and r.get("arm") == candidate
                     and r["seed"] in this.seeds), key=lambda r: r["seed"])
        if not rs:
            continue
        held = [r["held_out_success"] for r in rs]
        stages = _stages(task, candidate)
        reached = ", ".join(f"{1 + max(s['stage'] for s in r['task_stages'])}/{stages}"
                            for r in rs if r.get("task_stages")) if stages else "–"
        intrinsic = [r["intrinsic_reward_first_tenth"] for r in rs if "intrinsic_reward_first_tenth" in r]
        lines.append(f"| {task} | {candidate} | {', '.join(str(r['seed']) for r in rs)} | {cell_versions(rs)[0]} | "
                     f"{', '.join(f'{h:.3f}' for h in held)} | {np.mean(held):.3f} | "
                     f"{np.mean([r.get('final_tenth_success', 0.0) for r in rs]):.3f} | {reached or '–'} | "
                     f"{f'{np.mean(intrinsic):.4f}' if intrinsic else '–'} | "
                     f"{np.mean([r['episodes'] for r in rs]):,.0f} |")
    return "\n".join(lines)


def _round_name(this: ScreenRound) -> str:
    return f"round of seeds {', '.join(map(str, this.seeds))} ({', '.join(this.candidates)})"


def screen_choice_text(runs: list[dict[str, Any]]) -> str:
    """Per task: each stopped round of its screen and why (the protocol's amendments), then the choice of its current
    round (experiments.sparse_arms.sparse_choice) or what that still waits for."""
    out = []
    for task, rounds in SCREEN_ROUNDS.items():
        out += [f"- {task}, {_round_name(r)}: **no choice**: {r.stopped}." for r in rounds if r.stopped]
        if rounds[-1].stopped:
            continue
        try:
            choice = sparse_choice(runs, task)
        except SparseNotReady as waiting:
            out.append(f"- {task}: no choice yet; {waiting}.")
            continue
        ranked = "; ".join(f"{c} {m:.3f}" for c, m in sorted(choice.held_out.items(), key=lambda x: -x[1]))
        verdict = f"**{choice.candidate}** goes to the confirmation" if choice.candidate else \
            "**no candidate** (none solved a held-out episode): nothing is confirmed on this task"
        out.append(f"- {task}: {verdict}. Mean held-out success over seeds "
                   f"{', '.join(map(str, rounds[-1].seeds))}: {ranked}.")
    return "\n".join(out)


def _confirm_arms(runs: list[dict[str, Any]], task: str) -> dict[str, list[dict[str, Any]]]:
    """The confirmation's runs on `task` at its seeds by arm, the candidate first, then MADDPG, then the control."""
    rs = [r for r in runs if r.get("env") == task and r["seed"] in SPARSE_CONFIRM_SEEDS]
    arms = sorted({r["arm"] for r in rs}, key=lambda a: (a == "maddpg", a == "control", a))
    return {a: sorted((r for r in rs if r["arm"] == a), key=lambda r: r["seed"]) for a in arms}


def confirm_table(runs: list[dict[str, Any]]) -> str:
    """Per task and arm of the confirmation so far: seeds, code, held-out success (mean, min–max) and the training
    success over the last tenth (mean)."""
    lines = ["| task | arm | seeds | code | held-out success, mean (min–max) | training success, last tenth |",
             "| --- " * 6 + "|"]
    for task in SPARSE_SCREEN_TASKS:
        for arm, rs in _confirm_arms(runs, task).items():
            held = [r["held_out_success"] for r in rs]
            lines.append(f"| {task} | {arm} | {len(rs)} | {cell_versions(rs)[0]} | {np.mean(held):.3f} "
                         f"({min(held):.3f}–{max(held):.3f}) | "
                         f"{np.mean([r.get('final_tenth_success', 0.0) for r in rs]):.3f} |")
    return "\n".join(lines)


def confirm_tests(runs: list[dict[str, Any]]) -> str:
    """The confirmation's tests once every arm of a task has all of its seeds: per task, the candidate against
    MADDPG and against the control (one-sided Mann-Whitney U on held-out success), Holm-adjusted over every
    comparison of every complete task; then the goal's verdict per task (candidate mean >= GOAL_SUCCESS, MADDPG's
    < SUITE_LEVEL, both adjusted p < ALPHA)."""
    tests = []
    for task in SPARSE_SCREEN_TASKS:
        arms = _confirm_arms(runs, task)
        if len(arms) < 3 or any(len(rs) < len(SPARSE_CONFIRM_SEEDS) for rs in arms.values()):
            continue
        candidate = next(iter(arms))
        ours = [r["held_out_success"] for r in arms[candidate]]
        for other in ("maddpg", "control"):
            theirs = [r["held_out_success"] for r in arms[other]]
            p = float(stats.mannwhitneyu(ours, theirs, alternative="greater").pvalue)
            tests.append((task, candidate, other, float(np.mean(ours) - np.mean(theirs)), p, ours, theirs))
    if not tests:
        return "No task has all of its confirmation runs yet; no test is read before then."
    adjusted = holm([t[4] for t in tests])
    lines = ["| task | comparison | difference of mean held-out success | one-sided U p | Holm p | verdict |",
             "| --- " * 6 + "|"]
    for (task, candidate, other, diff, p, _, _), q in zip(tests, adjusted, strict=True):
        lines.append(f"| {task} | {candidate} > {other} | {diff:+.3f} | {p:.4f} | {q:.4f} | "
                     f"{'shown' if q < ALPHA else 'not shown'} |")
    for task in dict.fromkeys(t[0] for t in tests):
        mine = [(t, q) for t, q in zip(tests, adjusted, strict=True) if t[0] == task]
        ours, maddpg = mine[0][0][5], mine[0][0][6]
        met = np.mean(ours) >= GOAL_SUCCESS and np.mean(maddpg) < SUITE_LEVEL and all(q < ALPHA for _, q in mine)
        lines.append("")
        lines.append(f"Goal on {task} ({mine[0][0][1]}: mean ≥ {GOAL_SUCCESS} where MADDPG's < {SUITE_LEVEL}, above "
                     f"both at Holm α = {ALPHA}): **{'met' if met else 'not met'}** (the candidate "
                     f"{np.mean(ours):.3f}, MADDPG {np.mean(maddpg):.3f}).")
    return "\n".join(lines)

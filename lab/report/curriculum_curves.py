"""The curriculum figure's coverage panel in numbers (blocks curriculumhardcurves, curriculumstridecurves and
curriculumetacurves of lab/RESULTS.md, under the harder task's figures): per arm, the mean over its seeds of the
training coverage curve (WINDOW-episode windows, as the figure's panel a draws it) at its first window, the episodes
at which that mean first reaches 0.2 and 0.5 (interpolated between windows), and its value at a few episodes up to
the budget; then the mean episode at which λ reaches 0.5 (the figure's dotted line), or, where the arms' λ schedules
differ (the λ-stride grid; as the figure decides, `lambda_half_lines`), a column of it per arm. So the sentences
about the figure are read from the runs, not from the picture. Reads only the runs it is given.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from experiments.labels import ARM_LABEL, ARM_ORDER
from experiments.measures import WINDOW
from lab.report.curriculum_figure import lambda_half_lines
from lab.report.quoted_words import NO_RUNS

LEVELS = (0.2, 0.5)  # coverage levels whose first crossing by the mean curve the table gives
AT = (2_500, 5_000, 10_000, 20_000)  # episodes at which it gives the mean curve's value (those within the budget)


def mean_curve(runs: list[dict[str, Any]]) -> tuple[np.ndarray, np.ndarray]:
    """(episodes at each window's end: float64[W], mean coverage over runs: float64[W]) over the windows every run
    has."""
    n = min(len(r["curves"]["coverage"]) for r in runs)
    return (np.arange(n) + 1.0) * WINDOW, np.mean([r["curves"]["coverage"][:n] for r in runs], axis=0)


def first_reaches(episodes: np.ndarray, curve: np.ndarray, level: float) -> float | None:
    """The episode at which `curve` first reaches `level`, interpolated linearly from the window before (None:
    never; the first window's episode when it starts there)."""
    above = np.flatnonzero(curve >= level)
    if not above.size:
        return None
    i = int(above[0])
    if i == 0:
        return float(episodes[0])
    return float(np.interp(level, curve[i - 1:i + 1], episodes[i - 1:i + 1]))


def row(cells: list[str]) -> str:
    """One markdown table row."""
    return "| " + " | ".join(cells) + " |"


def curve_table(runs: list[dict[str, Any]], order: tuple[str, ...] = ARM_ORDER) -> str:
    """The per-arm table of the mean training coverage curve and the λ line, as markdown ('no runs yet' without),
    one row per arm of `order` that has runs (a settings grid's: its SETTING_TABLES arms); where the arms' λ
    schedules differ, a column "λ reaches 0.5" (each arm's mean episode, "—" for an arm without λ) instead of one
    mean over every arm."""
    if not runs:
        return NO_RUNS
    budget = max(r["budget"] for r in runs)
    arms = [a for a in order if any(r.get("arm") == a for r in runs)]
    half_lines = lambda_half_lines(runs, tuple(arms), budget)  # {None: episode} when the schedules agree, else per arm
    lambda_per_arm = bool(half_lines) and None not in half_lines
    at = [e for e in AT if e <= budget]
    header = ["arm", "seeds", *(["λ reaches 0.5"] if lambda_per_arm else []), "at the first window",
              *(f"first reaches {v}" for v in LEVELS), *(f"at episode {e:,}" for e in at)]
    lines = [row(header), "| --- " * len(header) + "|"]
    for arm in arms:
        mine = [r for r in runs if r.get("arm") == arm]
        episodes, curve = mean_curve(mine)
        reached = [first_reaches(episodes, curve, v) for v in LEVELS]
        half = [f"{half_lines[arm]:,.0f}" if arm in half_lines else "—"] if lambda_per_arm else []
        lines.append(row([ARM_LABEL[arm], str(len(mine)), *half, f"{curve[0]:.2f}",
                          *("never" if e is None else f"{e:,.0f}" for e in reached),
                          *(f"{np.interp(e, episodes, curve):.2f}" if e <= episodes[-1] else "—" for e in at)]))
    said = f"Mean training coverage over each arm's seeds ({WINDOW}-episode windows, the figure's panel a)"
    if lambda_per_arm:
        return "\n".join([*lines, "", said + "; λ reaches 0.5: each arm's mean episode (the dotted lines)."])
    half = half_lines.get(None)  # the mean over the table's arms' runs
    lines += ["", said + "; λ "
              + (f"reaches 0.5 at episode {half:,.0f} on average (the dotted line)." if half is not None else
                 "does not reach 0.5 in these runs.")]
    return "\n".join(lines)

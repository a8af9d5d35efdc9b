"""The curriculum figure's coverage panel in numbers (block curriculumhardcurves of docs/RESULTS.md, under the harder
task's figure): per arm, the mean over its seeds of the training coverage curve (WINDOW-episode windows, as the
figure's panel a draws it) at its first window, the episodes at which that mean first reaches 0.2 and 0.5
(interpolated between windows), and its value at a few episodes up to the budget; then the mean episode at which λ
reaches 0.5 (the figure's dotted line). So the sentences about the figure are read from the runs, not from the
picture. Reads only the runs it is given.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from experiments.curriculum_figure import episode_lambda_reaches
from experiments.labels import ARM_LABEL, ARM_ORDER
from experiments.measures import WINDOW
from experiments.quoted_words import NO_RUNS

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


def curve_table(runs: list[dict[str, Any]]) -> str:
    """The per-arm table of the mean training coverage curve and the λ line, as markdown ('no runs yet' without)."""
    if not runs:
        return NO_RUNS
    budget = max(r["budget"] for r in runs)
    at = [e for e in AT if e <= budget]
    header = ["arm", "seeds", "at the first window", *(f"first reaches {v}" for v in LEVELS),
              *(f"at episode {e:,}" for e in at)]
    lines = [row(header), "| --- " * len(header) + "|"]
    for arm in (a for a in ARM_ORDER if any(r.get("arm") == a for r in runs)):
        mine = [r for r in runs if r.get("arm") == arm]
        episodes, curve = mean_curve(mine)
        reached = [first_reaches(episodes, curve, v) for v in LEVELS]
        lines.append(row([ARM_LABEL[arm], str(len(mine)), f"{curve[0]:.2f}",
                          *("never" if e is None else f"{e:,.0f}" for e in reached),
                          *(f"{np.interp(e, episodes, curve):.2f}" if e <= episodes[-1] else "—" for e in at)]))
    half = episode_lambda_reaches(runs, 0.5)
    lines += ["", f"Mean training coverage over each arm's seeds ({WINDOW}-episode windows, the figure's panel a); λ "
              + (f"reaches 0.5 at episode {half:,.0f} on average (the dotted line)." if half is not None else
                 "does not reach 0.5 in these runs.")]
    return "\n".join(lines)

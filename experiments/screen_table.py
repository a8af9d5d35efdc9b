"""The screen of sampling rules (issue 36; protocol in docs/RESULTS.md, "Sampling rules that help: the screen"):
one row per arm with its learning measures, the manipulation check and the code it ran, then the selection rule
applied. The screen makes no claim: it only picks the candidates of the confirmation.

Manipulation check: over the progress rows of the first quarter of the run's episodes, the reward-bearing rows'
mean share of the sampled minibatches divided by their mean share of the buffer (`manipulation_ratio`); an arm whose
mean ratio over its seeds is >= 1 "acted".
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from cmcl.algorithms import spec_of
from experiments.labels import ARM_LABEL
from experiments.provenance import cell_versions
from experiments.screen_arms import SCREEN_ARMS, SCREEN_REFERENCES, SCREEN_SEEDS, rule_algorithm
from experiments.stats import fmt

SELECTED = 2  # candidates the selection rule picks


def manipulation_ratio(run: dict[str, Any]) -> float | None:
    """First-quarter mean sampled share / mean buffer share of reward-bearing rows (None without progress rows)."""
    curve = run.get("sampling_curve") or {}
    episodes = np.asarray(curve.get("episode", []), dtype=float)
    if episodes.size == 0:
        return None
    first = episodes <= run["budget"] / 4
    sampled = np.asarray(curve["reward_rows_sampled"], dtype=float)[first]
    buffer = np.asarray(curve["reward_rows_buffer"], dtype=float)[first]
    return float(sampled.mean() / buffer.mean()) if buffer.size and buffer.mean() > 0 else None


def arm_runs(runs: list[dict[str, Any]], arm: str) -> list[dict[str, Any]]:
    return sorted((r for r in runs if r.get("arm") == arm), key=lambda r: r["seed"])


def acted(rs: list[dict[str, Any]]) -> bool | None:
    """Whether the arm passed the manipulation check (mean ratio over its seeds >= 1); None without data."""
    ratios = [x for x in map(manipulation_ratio, rs) if x is not None]
    return None if not ratios else float(np.mean(ratios)) >= 1.0


def arm_table(runs: list[dict[str, Any]], roles: dict[str, str]) -> str:
    """Per arm of `roles` (arm -> its role in the grid, in table order): role, seeds, code, area under the training
    coverage curve, held-out coverage and success, episodes to MA 0.9, ESS in the first quarter, the manipulation
    ratio and its verdict."""
    lines = ["| arm | role | seeds | code | area under coverage | held-out coverage | held-out success | "
             "episodes to MA 0.9 | ESS, first quarter | reward rows sampled / buffer, first quarter | "
             "manipulation check |", "| --- " * 11 + "|"]
    for arm, role in roles.items():
        rs = arm_runs(runs, arm)
        if not rs:
            continue
        ratios = [x for x in map(manipulation_ratio, rs) if x is not None]
        check = "—" if arm == "maddpg" else "no data" if acted(rs) is None else \
            "acted" if acted(rs) else "did not act"
        ess = [r["ess_first_quarter"] for r in rs if r.get("ess_first_quarter") is not None]
        lines.append(f"| {ARM_LABEL[arm]} | {role} | {len(rs)} | {cell_versions(rs)[0]} | " + " | ".join(
                         fmt([r[k] for r in rs], d, k) for k, d in (("auc_coverage", 3), ("held_out_coverage", 3),
                                                                    ("held_out_success", 3), ("episodes_to_90", 0)))
                     + f" | {np.mean(ess):.2f} | " + (f"{np.mean(ratios):.2f}" if ratios else "—") + f" | {check} |")
    return "\n".join(lines)


def screen_table(runs: list[dict[str, Any]]) -> str:
    """The screen per arm (arm_table): the candidates and the references run beside them, and a note on the ESS of
    the arms whose learner picks among candidates, once one has a run."""
    table = arm_table(runs, {arm: "reference" if arm in SCREEN_REFERENCES else "candidate" for arm in SCREEN_ARMS})
    pickers = [ARM_LABEL[arm] for arm, sets in SCREEN_ARMS.items()
               if spec_of(rule_algorithm(sets)).candidates > 1 and arm_runs(runs, arm)]
    if not pickers:
        return table
    return table + (f"\n\nESS is that of the buffer's draw; for {', '.join(pickers)} that is the uniform candidate "
                    "batch (1.00 by construction), and the learner's pick among the candidates shows in the reward "
                    "rows' ratio, which the inline runner measures on the picked rows.")


@dataclass(frozen=True)
class Selection:
    """The screen's selection rule applied to its summaries. done, expected: the screen's finished runs (its arms at
    its seeds) and how many it has in all; code: their code version and testable whether they may be compared (one
    version, or fingerprints that agree), both read once the screen is complete; ranked: (mean area to 3 decimals,
    mean held-out success, arm) of the candidates that acted, best first; chosen: the SELECTED best of them, () while
    there is no selection."""

    done: int
    expected: int
    code: str = ""
    testable: bool = False
    ranked: tuple[tuple[float, float, str], ...] = ()
    chosen: tuple[str, ...] = ()

    @property
    def missing(self) -> int:
        return self.expected - self.done

    def reason(self) -> str:
        """Why there is no selection ("" when there is one)."""
        if self.missing:
            return f"Screen incomplete: {self.done} of {self.expected} runs; no selection yet."
        if not self.testable:
            return f"Screen runs ran different code ({self.code}); no selection."
        return "" if self.chosen else f"No candidate acted (code {self.code}): none is selected."


def selection(runs: list[dict[str, Any]]) -> Selection:
    """The selection rule: the SELECTED candidates with the highest mean area among those that acted (ties to 3
    decimals broken by held-out success), once every arm has its SCREEN_SEEDS and the runs ran one code version."""
    expected = len(SCREEN_ARMS) * len(SCREEN_SEEDS)
    done = [r for r in runs if r.get("arm") in SCREEN_ARMS and r["seed"] in SCREEN_SEEDS]
    if len(done) < expected:
        return Selection(len(done), expected)
    code, testable = cell_versions(done)
    if not testable:
        return Selection(len(done), expected, code)
    ranked = []
    for arm in SCREEN_ARMS:
        rs = arm_runs(done, arm)
        if arm in SCREEN_REFERENCES or not acted(rs):
            continue
        ranked.append((round(float(np.mean([r["auc_coverage"] for r in rs])), 3),
                       float(np.mean([r["held_out_success"] for r in rs])), arm))
    ranked.sort(reverse=True)
    return Selection(len(done), expected, code, True, tuple(ranked), tuple(arm for _, _, arm in ranked[:SELECTED]))


def screen_selection(runs: list[dict[str, Any]]) -> str:
    """The selection rule applied (`selection`), as the page says it."""
    chosen = selection(runs)
    if not chosen.chosen:
        return chosen.reason()
    return (f"Selected for the confirmation (code {chosen.code}): " + ", ".join(ARM_LABEL[a] for a in chosen.chosen)
            + ". Ranked by mean area among the candidates that acted: "
            + "; ".join(f"{ARM_LABEL[a]} {area:.3f}" for area, _, a in chosen.ranked) + ".")

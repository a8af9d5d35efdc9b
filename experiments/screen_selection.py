"""The screen's selection rule (protocol in lab/RESULTS.md, "Sampling rules that help: the screen"): which arms
round two runs once round one is in, and which candidates the finished screen selects for the confirmation, read
from the screen's summaries. The screen makes no claim: it only picks the candidates of the confirmation (its table
is drawn by the report, lab/report/screen_table.py).

Manipulation check: over the progress rows of the first quarter of the run's episodes, the reward-bearing rows'
mean share of the sampled minibatches divided by their mean share of the buffer (`manipulation_ratio`); an arm whose
mean ratio over its seeds is >= 1 "acted".
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from experiments.labels import ARM_LABEL
from experiments.provenance import cell_versions
from experiments.screen_arms import (
    ROUND_ONE_KEPT,
    ROUND_ONE_SEEDS,
    ROUND_TWO_REFERENCES,
    ROUND_TWO_SEEDS,
    SCREEN_ARMS,
    SCREEN_REFERENCES,
)

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






def mean_area(runs: list[dict[str, Any]], arm: str) -> float:
    """The mean area under the training coverage curve of `arm`'s runs in `runs`, to 3 decimals (as the screen's
    selection and the confirmation's interim look compare them)."""
    return round(float(np.mean([r["auc_coverage"] for r in arm_runs(runs, arm)])), 3)


def ranking(runs: list[dict[str, Any]], arms: Iterable[str]) -> list[tuple[float, float, str]]:
    """(mean area to 3 decimals, mean held-out success, arm) of the candidates among `arms` that acted in `runs`,
    best first (ties in area broken by held-out success)."""
    ranked = []
    for arm in arms:
        rs = arm_runs(runs, arm)
        if arm in SCREEN_REFERENCES or not rs or not acted(rs):
            continue
        ranked.append((mean_area(rs, arm), float(np.mean([r["held_out_success"] for r in rs])), arm))
    return sorted(ranked, reverse=True)


def at_seeds(runs: list[dict[str, Any]], seeds: Iterable[int]) -> list[dict[str, Any]]:
    """The screen's runs of `runs` (its arms) at `seeds`."""
    wanted = set(seeds)
    return [r for r in runs if r.get("arm") in SCREEN_ARMS and r["seed"] in wanted]


def round_two_arms(runs: list[dict[str, Any]]) -> tuple[str, ...] | None:
    """The arms of round two: ROUND_TWO_REFERENCES and the ROUND_ONE_KEPT candidates of round one with the highest
    area that acted (none at all when no candidate acted); None while round one misses a run."""
    first = at_seeds(runs, ROUND_ONE_SEEDS)
    if len(first) < len(SCREEN_ARMS) * len(ROUND_ONE_SEEDS):
        return None
    kept = tuple(arm for *_, arm in ranking(first, SCREEN_ARMS)[:ROUND_ONE_KEPT])
    return (*ROUND_TWO_REFERENCES, *kept) if kept else ()


def planned(runs: list[dict[str, Any]]) -> set[tuple[str, int]]:
    """The screen's (arm, seed) pairs as far as they are known: round one's, and round two's once round one is in."""
    pairs = {(arm, seed) for arm in SCREEN_ARMS for seed in ROUND_ONE_SEEDS}
    return pairs | {(arm, seed) for arm in round_two_arms(runs) or () for seed in ROUND_TWO_SEEDS}


# the screen's runs at most (round two with ROUND_ONE_KEPT candidates); fewer when fewer candidates of round one acted
EXPECTED = len(SCREEN_ARMS) * len(ROUND_ONE_SEEDS) + (len(ROUND_TWO_REFERENCES) + ROUND_ONE_KEPT) * len(ROUND_TWO_SEEDS)


@dataclass(frozen=True)
class Selection:
    """The screen's selection rule applied to its summaries. done, expected: the screen's finished runs (of the pairs
    `planned`) and how many it has in all; code: their code version and testable whether they may be compared (one
    version, or fingerprints that agree), both read once the screen is complete; ranked: (mean area to 3 decimals,
    mean held-out success, arm) over SCREEN_SEEDS of round two's candidates that acted, best first; reference:
    MADDPG's mean area over the same seeds; chosen: the SELECTED best of the ranked whose area exceeds the
    reference's, () while there is no selection; kept: round two's candidates once round one is in."""

    done: int
    expected: int  # EXPECTED until round one is in, then the planned runs' count
    code: str = ""
    testable: bool = False
    ranked: tuple[tuple[float, float, str], ...] = ()
    chosen: tuple[str, ...] = ()
    reference: float | None = None
    kept: tuple[str, ...] = ()

    @property
    def missing(self) -> int:
        return self.expected - self.done

    def reason(self) -> str:
        """Why there is no selection ("" when there is one)."""
        if self.missing:
            then = (f" Round one is in: round two runs {', '.join(ARM_LABEL[a] for a in self.kept)} at seeds "
                    f"{', '.join(map(str, ROUND_TWO_SEEDS))}." if self.kept else "")
            return f"Screen incomplete: {self.done} of {self.expected} runs; no selection yet.{then}"
        if not self.testable:
            return f"Screen runs ran different code ({self.code}); no selection."
        if self.chosen:
            return ""
        if not self.ranked:
            return f"No candidate acted (code {self.code}): none is selected."
        return (f"No candidate's mean area exceeded MADDPG's {self.reference:.3f} (code {self.code}): none is "
                f"selected, and the confirmation does not run.")


def selection(runs: list[dict[str, Any]]) -> Selection:
    """The selection rule: after round one, round two's candidates (`round_two_arms`); once every planned run is in
    and the runs ran one code version, the SELECTED candidates with the highest mean area over SCREEN_SEEDS among
    those that acted (ties to 3 decimals broken by held-out success) whose mean area exceeds MADDPG's there."""
    pairs = planned(runs)
    done = [r for r in runs if (r.get("arm"), r["seed"]) in pairs]
    second = round_two_arms(runs)
    kept = tuple(a for a in second or () if a not in ROUND_TWO_REFERENCES)
    expected = EXPECTED if second is None else len(pairs)
    if len(done) < expected:
        return Selection(len(done), expected, kept=kept)
    code, testable = cell_versions(done)
    if not testable:
        return Selection(len(done), expected, code, kept=kept)
    ranked = ranking(done, kept)
    reference = mean_area(done, "maddpg")
    chosen = tuple(arm for area, _, arm in ranked if area > reference)[:SELECTED]
    return Selection(len(done), expected, code, True, tuple(ranked), chosen, reference, kept)


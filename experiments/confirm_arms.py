"""The confirmation's arms (protocol in lab/RESULTS.md, "the confirmation's protocol"), derived from the
screen: the rules the screen's committed summaries select (`screen_choice`, by experiments.screen_selection.selection),
each with its permuted control, then MADDPG (`confirm_arms`); ConfirmNotReady while the screen has no selection or a
selected rule has no permuted control. Its seeds come in two halves: after the interim look at INTERIM_SEEDS, a rule
whose mean area does not exceed MADDPG's stops (`stopped_at_interim`), and the later seeds run only the others
(`arms_at_seed`). The registry (experiments.grids) makes the confirm grid's runs of these arms; this module reads the
screen's arms and the permuted control's key (experiments.screen_arms).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from cmcl.replay.priority import EPS_P
from cmcl.replay.registry import build_sampler, spec_of
from cmcl.replay.sampling import SamplerArgs
from experiments.labels import PERMUTED
from experiments.screen_arms import PERMUTED_CONTROL, SCREEN_ARMS, rule_algorithm
from experiments.screen_selection import mean_area, selection
from experiments.store import ResultsStore

CONFIRM_REFERENCES = ("maddpg",)  # beside the selected rules and their controls, never selected
CONFIRM_SEEDS = tuple(range(20))
# Amended on 2026-12-05 at 13:35 UTC, before any run of the confirmation (lab/RESULTS.md, "Amendment: the
# confirmation with an interim look"): PER-MADDPG is no longer an arm, and once every arm has INTERIM_SEEDS a rule
# whose mean area does not exceed MADDPG's stops (non-binding futility: it cannot raise the false positive rate).
INTERIM_SEEDS = CONFIRM_SEEDS[:10]


class ConfirmNotReady(ValueError):
    """The confirmation's arms cannot be derived: the screen has no selection yet, or a selected rule has no
    permuted control."""


def has_permuted_control(algorithm: str) -> bool:
    """Whether the permuted control acts on `algorithm`'s sampling. The buffer shuffles the priorities of the samplers
    that recompute them, and under the control a sampler recomputes exactly when it holds priorities of its own; a
    rule whose learner picks each minibatch among candidates (the registry's `candidates` > 1: LaBER, by a fresh
    |δ|) has those |δ| shuffled across its candidates (cmcl.replay.rules.laber.candidate_orders). Uniform replay
    has neither."""
    args = SamplerArgs(capacity=1, alpha=1.0, backend="cdf", eps=EPS_P, algorithm=algorithm, permuted=True)
    return bool(build_sampler(algorithm, args).recomputes) or spec_of(algorithm).pick is not None


def confirm_arms(chosen: Sequence[str]) -> dict[str, list[str]]:
    """The confirmation's arms (arm -> --set overrides) for the screen's chosen arms: each chosen arm with its screen
    overrides and its permuted control "<arm>_permuted" (the same overrides and PERMUTED_CONTROL), then MADDPG.
    ConfirmNotReady when a chosen rule has no permuted control (`has_permuted_control`)."""
    lacking = [arm for arm in chosen if not has_permuted_control(rule_algorithm(SCREEN_ARMS[arm]))]
    if lacking:
        raise ConfirmNotReady(f"the permuted control does not act on the selected {lacking} (no priorities held in "
                              f"the buffer, nor a pick among candidates, to shuffle); the confirmation's protocol "
                              f"needs one for each chosen rule")
    arms = {}
    for arm in chosen:
        arms[arm], arms[f"{arm}{PERMUTED}"] = SCREEN_ARMS[arm], [*SCREEN_ARMS[arm], PERMUTED_CONTROL]
    return arms | {arm: SCREEN_ARMS[arm] for arm in CONFIRM_REFERENCES}


def screen_choice(screen: Path) -> tuple[str, ...]:
    """The screen's selected arms from the summaries of the results folder `screen`; ConfirmNotReady, naming the
    screen runs still missing, while there is no selection."""
    chosen = selection(ResultsStore(screen).load())
    if not chosen.chosen:
        raise ConfirmNotReady(f"the confirmation's arms are the screen's selection and there is none yet: "
                              f"{chosen.missing} of {chosen.expected} screen runs missing in {screen}"
                              + ("" if chosen.missing else f" ({chosen.reason()})"))
    return chosen.chosen


def stopped_at_interim(runs: list[dict[str, Any]], chosen: Sequence[str]) -> tuple[str, ...] | None:
    """The chosen rules the interim look stops: those whose mean area under coverage over INTERIM_SEEDS does not exceed
    MADDPG's (both to 3 decimals); None while an arm of `confirm_arms(chosen)` misses an interim seed."""
    seeds = set(INTERIM_SEEDS)
    for arm in confirm_arms(chosen):
        if not {r["seed"] for r in runs if r.get("arm") == arm} >= seeds:
            return None
    interim = [r for r in runs if r["seed"] in seeds]
    return tuple(rule for rule in chosen if mean_area(interim, rule) <= mean_area(interim, "maddpg"))


def arms_at_seed(seed: int, chosen: Sequence[str], runs: list[dict[str, Any]]) -> dict[str, list[str]]:
    """The confirmation's arms at `seed` given its finished `runs`: every arm at an interim seed; after them, the arms
    of the rules the interim look did not stop (none while the interim look waits for runs, or stops every rule)."""
    if seed in INTERIM_SEEDS:
        return confirm_arms(chosen)
    stopped = stopped_at_interim(runs, chosen)
    going = [rule for rule in chosen if stopped is not None and rule not in stopped]
    return confirm_arms(going) if going else {}

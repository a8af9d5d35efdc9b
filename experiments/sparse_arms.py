"""The sparse screen's candidates and the confirmation's arms derived from them (docs/SPARSE_TASKS.md, "Screen
protocol" and "Confirmation protocol").

SPARSE_SCREEN names each candidate with its preset and overrides; SCREEN_ROUNDS gives each task's rounds of the screen
(candidates, seeds, and why a round stopped, if it did); `sparse_choice` reads the summaries of a task's current round
and picks one candidate (or none); `control_sets` gives the chosen candidate's control, the candidate's shape
without its information: a curriculum's stages on a fixed schedule (`fixed_window`), or curiosity's reward from a frozen
random ICM at the same scale (`frozen_coef`, from the `sparse_scale` reference runs). `confirm_arms` puts the three
arms of a task together. SparseNotReady says what is still missing. The registry (experiments.grids) makes the runs of
the sparse_screen, sparse_scale and sparse_confirm grids from these.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from cmcl.config import load_config
from experiments.run_spec import ROOT

# candidate -> (its preset configs/<task>_<kind>.toml, --set overrides), at the preset's budget
SPARSE_SCREEN = {
    "curriculum": ("curriculum", ()),
    "curriculum_progress": ("curriculum", ("task_curriculum.advance=progress", "task_curriculum.level=0.05")),
    "curriculum_nomix": ("curriculum", ("task_curriculum.mix=0.0",)),
    "curriculum_radius": ("radius", ()),  # the cover radius from 2.0 down: navigation's own
    "intrinsic": ("intrinsic", ()),
    "intrinsic_strong": ("intrinsic", ("icm.intrinsic_reward_coef=1.0",)),
    # vacl_n4's second round: its first stage plateaus below 0.8 at the presets' new learner settings
    "radius_half": ("radius", ("task_curriculum.level=0.5",)),
    "radius_progress": ("radius", ("task_curriculum.advance=progress", "task_curriculum.level=0.05")),
    "curriculum_half": ("curriculum", ("task_curriculum.level=0.5",)),
}
FIRST_ROUND = ("curriculum", "curriculum_progress", "curriculum_nomix", "intrinsic", "intrinsic_strong")


@dataclass(frozen=True)
class ScreenRound:
    """One round of a task's screen (docs/SPARSE_TASKS.md, its screen protocol and amendments): the candidates, in
    the order that breaks the last tie, and the seeds each runs at; `stopped`: why the round stopped before every
    seed ran ("" while it runs to its end; a stopped round's runs stay in the record and nothing chooses from
    them)."""

    candidates: tuple[str, ...]
    seeds: tuple[int, ...]
    stopped: str = ""


# task -> its screen's rounds, the last one the round the choice reads
SCREEN_ROUNDS = {
    "vacl_n4": (
        ScreenRound((*FIRST_ROUND[:3], "curriculum_radius", *FIRST_ROUND[3:]), (0, 1, 2), stopped=(
            "stopped after seed 0 (amendment of 2026-12-08): every arm's learner settings (maddpg.gamma 0.99, "
            "replay.capacity 5000) drive MADDPG's actors to ±1 and off the map within 3,000 episodes even at the "
            "easiest stage, so no candidate is compared with a working learner")),
        ScreenRound(("radius_half", "radius_progress", "curriculum_half"), (200, 201, 202)),  # fresh seeds
    ),
    "push_box": (
        ScreenRound(FIRST_ROUND, (0, 1, 2), stopped=(
            "stopped after seed 0 (amendment of 2026-12-08): every arm's replay.capacity of 5000 holds the last 16 "
            "episodes of 300 steps; with 500,000 the preset's curriculum reached the source task within 1,100 "
            "episodes, where every first-round curriculum stayed at 4 cells")),
        ScreenRound(FIRST_ROUND, (200, 201, 202)),  # fresh seeds, the presets' new buffer
    ),
}
SPARSE_SCREEN_TASKS = tuple(SCREEN_ROUNDS)
SPARSE_SCREEN_SEEDS = tuple(sorted({seed for rounds in SCREEN_ROUNDS.values() for r in rounds for seed in r.seeds}))


def current_round(task: str) -> ScreenRound:
    """The round of `task`'s screen the choice reads: its last."""
    return SCREEN_ROUNDS[task][-1]


CALIBRATION_SEEDS = (0, 1, 2)  # the calibration's and its recalibration's
SPARSE_CONFIRM_SEEDS = tuple(range(100, 110))  # fresh: the screen's seeds are never reused
SCALE_SECONDS = 300.0  # a frozen-ICM reference run: more than the first tenth of an 1,800 s run's updates
FROZEN_AT_COEF_1 = ("icm.frozen=true", "icm.intrinsic_reward_coef=1.0")


class SparseNotReady(ValueError):
    """The confirmation's arms cannot be derived yet: a screen or reference run is missing, or a chosen curriculum
    never left its first stage (no schedule to copy)."""


def config_of(task: str, candidate: str) -> str:
    """The preset a candidate trains `task` with: configs/<task>_<kind>.toml."""
    return f"{task}_{SPARSE_SCREEN[candidate][0]}.toml"


def is_curriculum(candidate: str) -> bool:
    """Whether the candidate is a task curriculum (else curiosity as a reward)."""
    return SPARSE_SCREEN[candidate][0] != "intrinsic"


@dataclass(frozen=True)
class SparseChoice:
    """The screen's choice on one task. candidate: the chosen one, None for "no candidate" (the best mean held-out
    success is 0); held_out / tenth: per candidate, its mean over the screen's seeds of held-out success and of the
    training success over the last 10 % of episodes (the tie-break), in SPARSE_SCREEN's order."""

    task: str
    candidate: str | None
    held_out: dict[str, float]
    tenth: dict[str, float]


def _screen_runs(summaries: Sequence[dict[str, Any]], task: str, candidates: Sequence[str]) -> dict[tuple, dict]:
    """The screen's summary of every (candidate, seed) of `task`'s current round; SparseNotReady naming the runs
    still missing."""
    have = {(s["arm"], s["seed"]): s for s in summaries if s.get("grid") == "sparse_screen" and s.get("env") == task}
    missing = [f"sparse_screen_{task}_{c}_s{seed}" for seed in current_round(task).seeds for c in candidates
               if (c, seed) not in have]
    if missing:
        more = f" and {len(missing) - 3} more" if len(missing) > 3 else ""
        raise SparseNotReady(f"the sparse screen on {task} misses {len(missing)} runs: {' '.join(missing[:3])}{more}")
    return have


def sparse_choice(summaries: Sequence[dict[str, Any]], task: str) -> SparseChoice:
    """The screen protocol's choice on `task` from the screen's summaries of its current round: the highest mean
    held-out success over the round's seeds; ties broken by the higher mean `final_tenth_success`, then by the round's
    order; None when the best mean is 0 (then no candidate solved a held-out episode). SparseNotReady while a run is
    missing."""
    this = current_round(task)
    candidates = list(this.candidates)
    runs = _screen_runs(summaries, task, candidates)

    def mean(candidate: str, key: str) -> float:
        return float(np.mean([runs[candidate, seed].get(key) or 0.0 for seed in this.seeds]))

    held = {c: mean(c, "held_out_success") for c in candidates}
    tenth = {c: mean(c, "final_tenth_success") for c in candidates}
    best = max(candidates, key=lambda c: (held[c], tenth[c], -candidates.index(c)))
    return SparseChoice(task, best if held[best] > 0 else None, held, tenth)


def fixed_window(summaries: Sequence[dict[str, Any]], task: str, candidate: str) -> int:
    """The curriculum control's `task_curriculum.window`: the median, pooled over the candidate's screen runs on
    `task`, of the episodes played at each stage it left (`task_stages`' episodes_at_stage, every span but a run's
    last), rounded to a multiple of the preset's env.num_envs (at least one). SparseNotReady when no run left its
    first stage."""
    runs = _screen_runs(summaries, task, [candidate])
    left = [span["episodes_at_stage"] for seed in current_round(task).seeds
            for span in (runs[candidate, seed].get("task_stages") or [])[:-1]]
    if not left:
        raise SparseNotReady(f"{candidate} on {task} never left its first stage in the screen: no schedule to fix")
    num_envs = load_config(ROOT / "configs" / config_of(task, candidate)).env.num_envs
    return max(num_envs, int(round(float(np.median(left)) / num_envs)) * num_envs)


def frozen_coef(screen: Sequence[dict[str, Any]], scale: Sequence[dict[str, Any]], task: str, candidate: str) -> float:
    """The intrinsic control's `icm.intrinsic_reward_coef`: the candidate's mean coef·ρ over its first 10 % of learner
    updates (`intrinsic_reward_first_tenth`, mean over the screen's seeds) over a frozen ICM's at coef 1 over the same
    updates of the same seed (the sparse_scale reference runs' `intrinsic_curve`, rows with updates <= a tenth of the
    candidate's). SparseNotReady while a reference run is missing or stopped short of that tenth."""
    runs = _screen_runs(screen, task, [candidate])
    refs = {s["seed"]: s for s in scale if s.get("id", "").startswith(f"sparse_scale_{task}_{candidate}_")}
    ours, frozen = [], []
    for seed in current_round(task).seeds:
        run, ref = runs[candidate, seed], refs.get(seed)
        tenth = 0.1 * int(run["updates"])
        if ref is None or not ref.get("intrinsic_curve") or max(ref["intrinsic_curve"]["updates"]) < tenth:
            raise SparseNotReady(f"the frozen-ICM reference sparse_scale_{task}_{candidate}_s{seed} is missing or "
                                 f"stopped before {tenth:.0f} updates (a tenth of the candidate's)")
        curve = ref["intrinsic_curve"]
        frozen.append(np.mean([v for u, v in zip(curve["updates"], curve["intrinsic_reward"], strict=True)
                               if u <= tenth]))
        ours.append(run["intrinsic_reward_first_tenth"])
    return round(float(np.mean(ours)) / float(np.mean(frozen)), 6)


def control_sets(screen: Sequence[dict[str, Any]], scale: Sequence[dict[str, Any]], task: str,
                 candidate: str) -> tuple[str, ...]:
    """The --set overrides of the chosen candidate's control: its own overrides, then a fixed schedule for a
    curriculum or a frozen ICM at the matched scale for curiosity."""
    own = SPARSE_SCREEN[candidate][1]
    if is_curriculum(candidate):
        window = fixed_window(screen, task, candidate)
        return (*own, "task_curriculum.advance=fixed", f"task_curriculum.window={window}")
    return (*own, "icm.frozen=true", f"icm.intrinsic_reward_coef={frozen_coef(screen, scale, task, candidate)}")


def confirm_arms(screen: Sequence[dict[str, Any]], scale: Sequence[dict[str, Any]],
                 task: str) -> dict[str, tuple[str, tuple[str, ...]]]:
    """The confirmation's arms on `task` (arm -> (config file, --set overrides)): the chosen candidate, uniform
    MADDPG and "control"; {} when the screen chose no candidate there."""
    chosen = sparse_choice(screen, task).candidate
    if chosen is None:
        return {}
    return {chosen: (config_of(task, chosen), SPARSE_SCREEN[chosen][1]), "maddpg": (f"{task}_maddpg.toml", ()),
            "control": (config_of(task, chosen), control_sets(screen, scale, task, chosen))}

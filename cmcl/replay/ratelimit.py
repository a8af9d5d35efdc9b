"""Rate limiter that holds one side's progress to a fixed ratio of another's (pure Python, no Ray).

Where it sits: DESIGN.md "data flow" step 7 and ALGORITHM.md §3.9. The supervisor in services/launch.py (and
`cmcl.loop`, trivially) asks one limiter per pair before handing out work:

* learner updates per env step: inserts = transitions accepted by the replay server (one per world step),
  samples = learner updates, ratio = 1 / maddpg.update_every, warm-up = maddpg.warmup transitions;
* teacher fit steps per learner update: inserts = learner updates, samples = teacher steps,
  ratio = teachers.steps_per_update;
* ICM steps per learner update: inserts = learner updates, samples = ICM steps, ratio = icm.steps_per_update.

So results do not depend on how fast each actor happens to run.

Rule. Let I and S be the inserts and samples recorded, W the warm-up and I_eff = max(0, I - W). The target is
S = ratio * I_eff; the deficit d = ratio * I_eff - S is how many samples the sampling side is behind.
No sample is allowed before I >= W. After that a request is granted only if it keeps -slack <= d <= slack:

* `can_sample(n)`: I >= W and d - n >= -slack (samples never run more than `slack` ahead of the target);
* `can_insert(n)`: ratio * max(0, I + n - W) - S <= slack (inserts never run more than `slack` samples'
  worth ahead; inserts that only fill the warm-up are always allowed).

Slack is measured in sample units. It must be at least (1 + ratio) / 2: then in every state one insert or one
sample is allowed, so neither side can block the other forever. A single request of more than 2·slack/ratio
inserts (or 2·slack samples) can never be granted: size slack to the largest chunk a caller records at once
(`limiters_from_config` does). `record_*` count what happened and never refuse, so the bounds hold as long as
callers ask `can_*` first; a side that over-records is simply held back until the other catches up.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from numbers import Real
from typing import Any

_EPS = 1e-9  # relative tolerance on float products such as 0.1 * 30


def _floor(x: float, scale: float) -> int:
    """floor(x), forgiving rounding error of relative size _EPS on numbers of magnitude `scale`."""
    return math.floor(x + _EPS * max(1.0, abs(scale)))


def _check_count(name: str, n: Any) -> int:
    """A non-negative int (bools refused), else ValueError naming the argument."""
    if isinstance(n, bool) or not isinstance(n, int) or n < 0:
        raise ValueError(f"{name} must be an integer >= 0, got {n!r}")
    return n


class RateLimiter:
    """Holds samples : inserts at `ratio` after `warmup` inserts, within ±`slack` samples (see module docstring)."""

    def __init__(self, ratio: float, warmup: int = 0, slack: float = 1.0):
        if isinstance(ratio, bool) or not isinstance(ratio, Real) or not (math.isfinite(ratio) and ratio > 0):
            raise ValueError(f"ratio must be a finite number > 0, got ratio={ratio!r}")
        _check_count("warmup", warmup)
        if isinstance(slack, bool) or not isinstance(slack, Real) or not math.isfinite(slack) or slack < 0:
            raise ValueError(f"slack must be a finite number >= 0, got slack={slack!r}")
        if slack < (1 + ratio) / 2:
            raise ValueError(f"slack must be >= (1 + ratio) / 2 = {(1 + ratio) / 2:g} so that an insert or a sample "
                             f"is always allowed, got slack={slack!r} (ratio={ratio!r})")
        self.ratio, self.warmup, self.slack = float(ratio), warmup, float(slack)
        self.inserts = 0
        self.samples = 0

    @property
    def warmed_up(self) -> bool:
        """True once `warmup` inserts have been recorded (sampling may start)."""
        return self.inserts >= self.warmup

    @property
    def deficit(self) -> float:
        """Samples behind the target ratio * max(0, inserts - warmup); negative when samples are ahead."""
        return self.ratio * max(0, self.inserts - self.warmup) - self.samples

    def allowed_samples(self) -> int:
        """Largest n with can_sample(n): 0 during warm-up, else floor(deficit + slack)."""
        if not self.warmed_up:
            return 0
        return max(0, _floor(self.deficit + self.slack, self.samples + self.slack))

    def allowed_inserts(self) -> int:
        """Largest n with can_insert(n): the rest of the warm-up plus what keeps deficit <= slack."""
        effective_max = _floor((self.slack + self.samples) / self.ratio, self.inserts)  # max I_eff allowed
        return max(0, self.warmup + effective_max - self.inserts)

    def can_sample(self, n: int = 1) -> bool:
        """Whether n samples (learner updates, teacher steps, ...) may run now."""
        return _check_count("n", n) <= self.allowed_samples()

    def can_insert(self, n: int = 1) -> bool:
        """Whether n inserts (transitions, learner updates, ...) may be accepted now."""
        return _check_count("n", n) <= self.allowed_inserts()

    def record_sample(self, n: int = 1) -> None:
        """Count n samples that happened."""
        self.samples += _check_count("n", n)

    def record_insert(self, n: int = 1) -> None:
        """Count n inserts that happened."""
        self.inserts += _check_count("n", n)

    def state_dict(self) -> dict[str, int | float]:
        """Counters and settings as plain ints / floats."""
        return {"ratio": self.ratio, "warmup": self.warmup, "slack": self.slack,
                "inserts": self.inserts, "samples": self.samples}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore the counters; the settings in `state` must equal this limiter's (ValueError naming the key)."""
        missing = sorted({"ratio", "warmup", "slack", "inserts", "samples"} - set(state))
        if missing:
            raise ValueError(f"rate limiter state lacks key {missing[0]!r}")
        for key in ("ratio", "warmup", "slack"):
            if state[key] != getattr(self, key):
                raise ValueError(f"rate limiter state has {key}={state[key]!r}, this limiter has "
                                 f"{key}={getattr(self, key)!r}")
        self.inserts = _check_count("inserts", state["inserts"])
        self.samples = _check_count("samples", state["samples"])

    def __repr__(self) -> str:
        return (f"RateLimiter(ratio={self.ratio:g}, warmup={self.warmup}, slack={self.slack:g}, "
                f"inserts={self.inserts}, samples={self.samples})")


def slack_for(ratio: float, insert_chunk: int = 1, sample_chunk: int = 1) -> float:
    """Smallest comfortable slack: max((1 + ratio) / 2, ratio * insert_chunk, sample_chunk).

    Any single request up to `insert_chunk` inserts or `sample_chunk` samples can then be granted (each needs
    at most 2·slack of room), with the rest as headroom so the two sides overlap instead of alternating.
    """
    _check_count("insert_chunk", insert_chunk)
    _check_count("sample_chunk", sample_chunk)
    return max((1 + ratio) / 2, ratio * insert_chunk, float(sample_chunk))


@dataclass
class Limiters:
    """The rate limiters of one run: the learner's (updates per env step), one per teacher fold and the ICM's (fit
    steps per learner update); teachers is [] and icm None when no team uses them."""

    learner: RateLimiter
    teachers: list[RateLimiter]
    icm: RateLimiter | None

    @property
    def scorers(self) -> list[RateLimiter]:
        """The limiters of every teacher fold and of the ICM."""
        return [*self.teachers, *([self.icm] if self.icm is not None else [])]


def limiters_from_config(config: Any, insert_chunk: int = 1, fit_chunk: int = 1,
                         extra_slack: float = 0.0) -> Limiters:
    """The limiters of a `cmcl.config.Config` (units in the module docstring): the one place the ratios
    (`maddpg.update_every`, `teachers.steps_per_update`, `icm.steps_per_update`) become limiters.

    Teachers (one per fold) / the ICM only when some team uses them (otherwise they would hold the learner back for
    nothing). A learner update may run when learner.can_sample(1) and, for each scorer, can_insert(1); record it
    with learner.record_sample(1) and the scorers' record_insert(1). `insert_chunk`: the most transitions recorded
    at once (one rollout chunk: num_envs × steps per chunk); `fit_chunk`: the most fit steps handed out at once;
    `extra_slack` (learner updates): how far the asynchronous sides may drift apart beyond that
    (`service.slack_updates`): the learner's slack is at least it, each scorer's grows by it.
    """
    learner_ratio = 1.0 / config.maddpg.update_every
    learner = RateLimiter(learner_ratio, warmup=config.maddpg.warmup,
                          slack=max(slack_for(learner_ratio, insert_chunk=insert_chunk), float(extra_slack)))
    teams = config.teams.values()
    teachers, icm = [], None
    if any(t.uses_teachers for t in teams):
        ratio = config.teachers.steps_per_update
        slack = slack_for(ratio, sample_chunk=fit_chunk) + extra_slack
        teachers = [RateLimiter(ratio, slack=slack) for _ in range(config.teachers.num_folds)]
    if any(t.uses_icm for t in teams):
        icm = RateLimiter(config.icm.steps_per_update, slack=slack_for(config.icm.steps_per_update,
                                                                         sample_chunk=fit_chunk) + extra_slack)
    return Limiters(learner, teachers, icm)


def steps_due(updates: int, ratio: float, counters: dict[str, int], key: str) -> int:
    """The inline loop's form of a ratio limit: fit steps to run at update number `updates` (0-based) so that
    counters[key] == floor((updates + 1) · ratio) afterwards (the ratio the service's limiters hold); counts them
    in counters[key]."""
    due = max(0, math.floor((updates + 1) * ratio + 1e-9) - counters[key])
    counters[key] += due
    return due

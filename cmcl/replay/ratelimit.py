"""Rate limiter that holds one side's progress to a fixed ratio of another's (pure Python, no Ray).

Where it sits: DESIGN.md "data flow" step 7 and ALGORITHM.md §3.9. `cmcl.replay.pacing.Pacing` holds one limiter
per pair, for both runners (the replay server asks it before handing out work, the inline loop asks what is due):

* learner updates per env step: inserts = transitions stored (one per world step), samples = learner updates,
  ratio = 1 / maddpg.update_every, warm-up = the buffer's minimum size;
* teacher fit steps per learner update: inserts = learner updates, samples = teacher steps,
  ratio = teachers.steps_per_update;
* ICM steps per learner update: inserts = learner updates, samples = ICM steps, ratio = icm.steps_per_update.

So results do not depend on how fast each actor happens to run.

Rule. Let I and S be the inserts and samples recorded, W the warm-up, O <= W the origin of the target (W unless
given) and I_eff = max(0, I - O). The target is S = ratio * I_eff; the deficit d = ratio * I_eff - S is how many
samples the sampling side is behind. No sample is allowed before I >= W. After that:

* `due()`: floor(d), the samples owed exactly (the synchronous form: the inline loop runs what is due at once);
* `can_sample(n)`: I >= W and d - n >= -slack (samples never run more than `slack` ahead of the target);
* `can_insert(n)`: ratio * max(0, I + n - O) - S <= slack, or I + n <= W (inserts never run more than `slack`
  samples' worth ahead; inserts that only fill the warm-up are always allowed).

Slack is measured in sample units. It must be at least (1 + ratio) / 2, so that in every state one insert or one
sample is allowed (neither side can block the other forever), and at least ratio * (W - O), so that filling the
warm-up keeps d <= slack. A single request of more than
2·slack/ratio inserts (or 2·slack samples) can never be granted: size slack to the largest chunk a caller records
at once (`cmcl.replay.pacing.pacing_from_config` does). `record_*` count what happened and never refuse, so the
bounds hold as long as callers ask `can_*` first; a side that over-records is simply held back until the other
catches up.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from numbers import Real
from typing import Any

from cmcl.replay.snapshot import OlderRunError, older_run

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
    """Holds samples : inserts at `ratio` counted from `start` inserts (default `warmup`), no sample before `warmup`
    inserts, within ±`slack` samples (see module docstring)."""

    def __init__(self, ratio: float, warmup: int = 0, slack: float = 1.0, start: int | None = None):
        if isinstance(ratio, bool) or not isinstance(ratio, Real) or not (math.isfinite(ratio) and ratio > 0):
            raise ValueError(f"ratio must be a finite number > 0, got ratio={ratio!r}")
        _check_count("warmup", warmup)
        start = warmup if start is None else _check_count("start", start)
        if start > warmup:
            raise ValueError(f"start must be <= warmup ({warmup}), got start={start!r}")
        if isinstance(slack, bool) or not isinstance(slack, Real) or not math.isfinite(slack) or slack < 0:
            raise ValueError(f"slack must be a finite number >= 0, got slack={slack!r}")
        least = max((1 + ratio) / 2, ratio * (warmup - start))
        if slack < least:
            raise ValueError(f"slack must be >= max((1 + ratio) / 2, ratio * (warmup - start)) = {least:g} so that an "
                             f"insert or a sample is always allowed and the warm-up keeps the deficit <= slack, "
                             f"got slack={slack!r} (ratio={ratio!r})")
        self.ratio, self.warmup, self.slack, self.start = float(ratio), warmup, float(slack), start
        self.inserts = 0
        self.samples = 0

    @property
    def warmed_up(self) -> bool:
        """True once `warmup` inserts have been recorded (sampling may start)."""
        return self.inserts >= self.warmup

    @property
    def deficit(self) -> float:
        """Samples behind the target ratio * max(0, inserts - start); negative when samples are ahead."""
        return self.ratio * max(0, self.inserts - self.start) - self.samples

    def due(self) -> int:
        """Samples owed now, exactly (the synchronous form, no slack): 0 during warm-up, else max(0, floor(deficit))."""
        if not self.warmed_up:
            return 0
        return max(0, _floor(self.deficit, self.ratio * self.inserts))

    def allowed_samples(self) -> int:
        """Largest n with can_sample(n): 0 during warm-up, else floor(deficit + slack)."""
        if not self.warmed_up:
            return 0
        return max(0, _floor(self.deficit + self.slack, self.samples + self.slack))

    def allowed_inserts(self) -> int:
        """Largest n with can_insert(n): the rest of the warm-up, or what keeps deficit <= slack if more."""
        effective_max = _floor((self.slack + self.samples) / self.ratio, self.inserts)  # max I_eff allowed
        return max(0, max(self.warmup, self.start + effective_max) - self.inserts)

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
        return {"ratio": self.ratio, "warmup": self.warmup, "slack": self.slack, "start": self.start,
                "inserts": self.inserts, "samples": self.samples}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore the counters; the settings in `state` must equal this limiter's (ValueError naming the key)."""
        missing = sorted({"ratio", "warmup", "slack", "start", "inserts", "samples"} - set(state))
        if missing:
            raise OlderRunError(older_run(f"rate limiter state without {missing[0]!r}"))
        for key in ("ratio", "warmup", "slack", "start"):
            if state[key] != getattr(self, key):
                raise ValueError(f"rate limiter state has {key}={state[key]!r}, this limiter has "
                                 f"{key}={getattr(self, key)!r}")
        self.inserts = _check_count("inserts", state["inserts"])
        self.samples = _check_count("samples", state["samples"])

    def __repr__(self) -> str:
        return (f"RateLimiter(ratio={self.ratio:g}, warmup={self.warmup}, start={self.start}, slack={self.slack:g}, "
                f"inserts={self.inserts}, samples={self.samples})")


def slack_for(ratio: float, insert_chunk: int = 1, sample_chunk: int = 1) -> float:
    """Smallest comfortable slack: max((1 + ratio) / 2, ratio * insert_chunk, sample_chunk).

    Any single request up to `insert_chunk` inserts or `sample_chunk` samples can then be granted (each needs
    at most 2·slack of room), with the rest as headroom so the two sides overlap instead of alternating.
    """
    _check_count("insert_chunk", insert_chunk)
    _check_count("sample_chunk", sample_chunk)
    return max((1 + ratio) / 2, ratio * insert_chunk, float(sample_chunk))

"""What a service run counts over all its segments: the supervisor's tallies as its summary gives them and its
checkpoint keeps them (checkpoints/service/supervisor.json), so that a resumed run's summary counts the whole run, as
its elapsed_s does. Pure: no Ray."""

from __future__ import annotations

from typing import Any

from services.runtime.call_budget import HeldClock
from services.runtime.failures import Failures


def tallies(failures: Failures, held: HeldClock, checkpoint_seconds: list[float]) -> dict[str, Any]:
    """{failures, hung: calls per role; recovery_s: seconds per role, in order; checkpoint_seconds: each
    checkpoint's; learner_held_s: seconds the learner had no call, by why}."""
    return {"failures": dict(failures.counts), "hung": dict(failures.hung),
            "recovery_s": {k: list(v) for k, v in failures.recovery.times.items()},
            "checkpoint_seconds": list(checkpoint_seconds), "learner_held_s": dict(held.seconds)}


def add_tallies(earlier: dict[str, Any], failures: Failures, held: HeldClock, checkpoint_seconds: list[float]) -> None:
    """On resume: the earlier segments' `tallies` (from the checkpoint) added, in place, to this segment's."""
    for mine, theirs in ((failures.counts, earlier["failures"]), (failures.hung, earlier["hung"]),
                         (held.seconds, earlier["learner_held_s"])):
        for key, value in theirs.items():
            mine[key] = mine.get(key, 0) + value
    for role, seconds in earlier["recovery_s"].items():
        failures.recovery.times[role] = [*seconds, *failures.recovery.times.get(role, [])]
    checkpoint_seconds[:0] = earlier["checkpoint_seconds"]

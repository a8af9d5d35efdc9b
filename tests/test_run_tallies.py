"""A service run's tallies over its segments (services.observability.run_tallies), without Ray: a resumed run adds the
earlier segments' counts, seconds and recovery times to its own."""

from cmcl.config import Config
from services.observability.run_tallies import add_tallies, tallies
from services.runtime.call_budget import HeldClock
from services.runtime.failures import Failures


def segment(failed: dict[str, int], recovered: dict[str, list[float]], held: float, checkpoints: list[float]):
    failures, clock = Failures(Config(), roles=None), HeldClock()  # the roles are not read by the bookkeeping
    failures.counts.update(failed)
    failures.recovery.times.update({k: list(v) for k, v in recovered.items()})
    clock.seconds["warmup"] = held
    return failures, clock, list(checkpoints)


def test_a_resumed_segment_counts_the_earlier_ones_too():
    first = tallies(*segment({"teacher": 2}, {"teacher": [0.5, 0.7]}, 3.0, [0.1, 0.2]))
    failures, clock, checkpoints = segment({"teacher": 1, "icm": 1}, {"teacher": [0.4]}, 0.0, [0.3])
    add_tallies(first, failures, clock, checkpoints)
    both = tallies(failures, clock, checkpoints)
    assert both["failures"] == {"teacher": 3, "icm": 1}
    assert both["recovery_s"] == {"teacher": [0.5, 0.7, 0.4]} and both["checkpoint_seconds"] == [0.1, 0.2, 0.3]
    assert both["learner_held_s"]["warmup"] == 3.0 and set(both["learner_held_s"]) == set(HeldClock.REASONS)

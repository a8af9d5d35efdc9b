"""bench/service_throughput.py measures the steady state: from the first row after warm-up to the row that counts
the last env step, leaving out the service's catch-up tail (updates only, no env steps)."""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from service_throughput import DEFAULT_EPISODES, steady_rates  # noqa: E402


class Rows:
    """A run directory's progress rows: (elapsed_s, env_steps, updates)."""

    path = "runs/fake"

    def __init__(self, rows):
        self._rows = [{"kind": "progress", "elapsed_s": t, "env_steps": s, "updates": u} for t, s, u in rows]

    def rows(self, kind):
        return self._rows if kind == "progress" else []


# warm-up (no updates), 10 s of steady state at 1000 env steps/s and 62.5 updates/s, then 5 s of catch-up
SERVICE = Rows([(1, 2000, 0), (2, 4000, 0), (3, 5000, 10), (8, 10000, 322.5), (13, 15000, 635), (15, 15000, 900),
                (18, 15000, 1000)])


def test_the_catch_up_tail_is_left_out():
    steady = steady_rates(SERVICE, while_collecting=True)
    assert steady["seconds"] == 10 and steady["env_steps_per_s"] == 1000 and steady["updates_per_s"] == 62.5
    whole = steady_rates(SERVICE)  # the former window: to the last row, env steps/s diluted by the tail
    assert whole["seconds"] == 15 and whole["env_steps_per_s"] == pytest.approx(10000 / 15)


def test_too_short_a_run_is_refused_and_the_default_is_long():
    with pytest.raises(RuntimeError, match="raise --episodes"):
        steady_rates(Rows([(1, 2000, 0), (2, 3000, 5), (3, 3000, 9)]), while_collecting=True)
    assert DEFAULT_EPISODES >= 2000

"""cmcl.progress.rates: counters' growth per second over a trailing window (the service's rates)."""

import pytest

from cmcl.progress.rates import WindowedRate


def test_the_first_mark_has_nothing_to_compare_with():
    assert WindowedRate(10.0).mark(0.0, (0.0, 0.0)) is None


def test_growth_per_second_since_the_newest_mark_at_the_windows_start():
    rate = WindowedRate(10.0)
    rate.mark(0.0, (0.0,))
    assert rate.mark(4.0, (40.0,)) == (10.0,)  # younger than the window: since the oldest mark
    assert rate.mark(8.0, (40.0,)) == (5.0,)  # no growth since 4 s, but within the window
    assert rate.mark(14.0, (100.0,)) == (60.0 / 10.0,)  # base: the mark of 4 s, the newest at or before 14 - 10
    assert rate.mark(30.0, (100.0,)) == (0.0,)  # nothing grew over the last 10 s (base the mark of 14 s)


def test_bursty_reports_never_read_zero_while_the_counter_grows():
    # the learner reports 16 updates every 3 s; a line refreshes every second: over the last refresh alone the rate
    # was 0 two times in three
    rate, updates, seen = WindowedRate(10.0), 0, []
    for t in range(60):
        if t % 3 == 0:
            updates += 16
        out = rate.mark(float(t), (updates,))
        if t >= 3:
            seen.append(out[0])
    assert min(seen) > 0 and all(abs(r - 16 / 3) < 2.5 for r in seen[10:]), seen


def test_a_window_must_be_positive_and_counts_must_match():
    with pytest.raises(ValueError, match="window"):
        WindowedRate(0.0)
    rate = WindowedRate(5.0)
    rate.mark(0.0, (1.0, 2.0))
    with pytest.raises(ValueError):
        rate.mark(1.0, (1.0,))

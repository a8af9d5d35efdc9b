"""The early-stopping rule shared by the inline loop and the service."""

from types import SimpleNamespace

from cmcl.progress import solved, window_mean

RUN = SimpleNamespace(stop_coverage=0.9, smoothing_window=4)


def rows(*coverage):
    return [{"coverage": c} for c in coverage]


def test_a_full_window_at_the_target_is_solved():
    assert solved(rows(0.75, 1.0, 1.0, 0.85), RUN)  # mean 0.9
    assert not solved(rows(0.75, 1.0, 1.0, 0.8), RUN)  # mean 0.8875


def test_a_window_that_is_not_full_yet_never_counts():
    assert not solved(rows(1.0, 1.0, 1.0), RUN)


def test_off_or_without_coverage_never_stops():
    assert not solved(rows(1.0, 1.0, 1.0, 1.0), SimpleNamespace(stop_coverage=0.0, smoothing_window=4))
    assert not solved([{"predator_win": 1.0}] * 4, RUN)
    assert window_mean([], "coverage") is None and window_mean(rows(0.5, 1.0), "coverage") == 0.75

"""Episode metrics (ALGORITHM.md §6.3): cover matrix, coverage rate, success as a perfect matching, predator win."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from cmcl.envs import metrics


def _brute_force_success(cover: np.ndarray) -> bool:
    """cover: bool[N, L]; some injective landmark -> agent assignment inside the cover relation."""
    n, num_l = cover.shape
    return any(all(cover[p[l], l] for l in range(num_l)) for p in itertools.permutations(range(n), num_l))


@pytest.mark.parametrize(("n", "num_l", "density"), [(4, 4, 0.35), (4, 4, 0.6), (3, 3, 0.5), (5, 4, 0.4), (3, 4, 0.9)])
def test_success_is_a_perfect_matching(n: int, num_l: int, density: float) -> None:
    rng = np.random.default_rng(n * 10 + num_l)
    cover = rng.random((400, n, num_l)) < density
    expected = np.array([_brute_force_success(c) for c in cover])
    np.testing.assert_array_equal(metrics.success(cover), expected)
    assert 0 < expected.sum() < len(expected) or n < num_l


def test_augmenting_path_fallback_agrees_with_hall(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(1)
    cover = rng.random((300, 6, 6)) < 0.3
    hall = metrics.success(cover)
    monkeypatch.setattr(metrics, "_HALL_MAX_LANDMARKS", 0)
    np.testing.assert_array_equal(metrics.success(cover), hall)
    assert 0 < hall.sum() < len(hall)


def test_stacked_agents_do_not_succeed_but_cover() -> None:
    landmarks = np.array([[[0.0, 0.0], [0.05, 0.0]]])  # two landmarks 0.05 apart
    one_agent_each = np.array([[[0.0, 0.01], [0.05, 0.01]]])
    both_on_first = np.array([[[0.0, 0.01], [0.01, 0.0]]])
    for agents, ok in ((one_agent_each, True), (both_on_first, True)):
        cover = metrics.cover_matrix(agents, landmarks)
        assert metrics.coverage_rate(cover)[0] == 1.0 and metrics.success(cover)[0] == ok
    far = np.array([[[0.0, 0.01], [0.4, 0.4]]])
    cover = metrics.cover_matrix(far, landmarks)  # one agent near both landmarks, the other away
    assert metrics.coverage_rate(cover)[0] == 1.0 and not metrics.success(cover)[0]


def test_cover_threshold_is_strict_and_vectorised() -> None:
    agents = np.array([[[0.1, 0.0]], [[0.0999, 0.0]], [[0.3, 0.3]]])  # B = 3, one agent each
    landmarks = np.zeros((3, 1, 2))
    cover = metrics.cover_matrix(agents, landmarks, radius=0.1)
    np.testing.assert_array_equal(cover[:, 0, 0], [False, True, False])
    np.testing.assert_array_equal(metrics.coverage_rate(cover), [0.0, 1.0, 0.0])


def test_predator_win_needs_one_capture() -> None:
    np.testing.assert_array_equal(metrics.predator_win(np.array([0, 1, 7])), [False, True, True])

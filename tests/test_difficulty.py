"""The difficulty table (eq. 11 over the teachers that have scored a row's current content)."""

import numpy as np
import pytest

from cmcl.scorers.difficulty import DifficultyTable, ScoreStamps

K, A = 4, 2


def test_partial_scores_scale_to_the_sum_over_all_blind_teachers():
    table = DifficultyTable(capacity=6, num_agents=A, num_folds=K)
    slots, gens, fold = np.arange(6), np.zeros(6, np.int64), np.array([0, 1, 2, 3, 0, 1])
    c, ok = table.difficulty(slots, gens, fold)
    assert not ok.any() and (c == 0).all(), "nothing scored yet"
    errors = np.ones((6, A, 1), np.float32)
    assert table.record(slots, gens, fold, [2], 2 * errors, stamp=7) == 5, "teacher 2 never scores its own row"
    c, ok = table.difficulty(slots, gens, fold)
    np.testing.assert_array_equal(ok, fold != 2)
    np.testing.assert_allclose(c[ok], 2.0 * (K - 1))  # one blind teacher has scored: (K-1)·mean
    for f in (0, 1, 3):
        table.record(slots, gens, fold, [f], errors, stamp=9)
    c, ok = table.difficulty(slots, gens, fold)
    want = np.where(fold == 2, 3.0, 2.0 + 2.0)[:, None].repeat(A, 1)  # sum over the K-1 teachers i != f(j)
    assert ok.all()
    np.testing.assert_allclose(c, want)
    stamps = table.stamps(slots, gens)
    assert (stamps[np.arange(6), fold] == -1).all() and stamps[0, 2] == 7 and stamps[0, 1] == 9


def test_an_overwritten_slot_forgets_the_errors_of_its_old_content():
    table = DifficultyTable(capacity=2, num_agents=1, num_folds=K)
    slots, fold = np.arange(2), np.array([0, 1])
    table.record(slots, np.zeros(2, np.int64), fold, [2, 3], np.full((2, 1, 2), 5.0, np.float32), stamp=1)
    new_generation = np.ones(2, np.int64)
    c, ok = table.difficulty(slots, new_generation, fold)
    assert not ok.any() and (table.stamps(slots, new_generation) == -1).all()


def test_state_round_trip_and_shape_check():
    table = DifficultyTable(capacity=3, num_agents=A, num_folds=K)
    table.record(np.arange(3), np.zeros(3, np.int64), np.array([0, 1, 2]), [3],
                 np.random.default_rng(0).random((3, A, 1)).astype(np.float32), stamp=4)
    other = DifficultyTable(capacity=3, num_agents=A, num_folds=K)
    other.load_state_dict(table.state_dict())
    for key, value in table.state_dict().items():
        np.testing.assert_array_equal(other.state_dict()[key], value)
    before = {k: v.copy() for k, v in other.state_dict().items()}
    with pytest.raises(ValueError, match=r"difficulty table error has shape \(4, 2, 4\), expected \(3, 2, 4\)"):
        other.load_state_dict(DifficultyTable(4, A, K).state_dict())
    with pytest.raises(ValueError, match="score stamps generation"):
        other.load_state_dict({**table.state_dict(), "generation": np.zeros((3, 1), np.int64)})
    for key, value in before.items():
        np.testing.assert_array_equal(other.state_dict()[key], value)  # a refused state changed nothing


def test_score_stamps_mark_one_column():
    stamps = ScoreStamps(capacity=3, columns=1)
    stamps.mark(np.array([1]), np.array([5]), 0, stamp=12)
    np.testing.assert_array_equal(stamps.stamps(np.arange(3), np.array([0, 5, 0]))[:, 0], [-1, 12, -1])

"""The scoring state and the one rescoring rule of the replay server, whichever runner schedules it
(cmcl.scorers.scoring; ALGORITHM.md §3.8, §3.9, A11)."""

import numpy as np
import pytest

from cmcl.replay.buffer import ReplayBuffer
from cmcl.scorers.scoring import ScoringState, oldest_first
from tests.buffers import make_buffer

pytestmark = pytest.mark.filterwarnings("error")
N, K, CAP = 2, 3, 30


def buffer_with(rows: int, episode_len: int = 5) -> ReplayBuffer:
    rb = make_buffer(capacity=CAP, n_agents=N, obs_dim=1, act_dim=1, n_folds=K, algorithms="cmcl")
    z = np.zeros((rows, N, 1), np.float32)
    rb.add(z, z, np.zeros((rows, N), np.float32), z, np.zeros(rows, np.float32), np.arange(rows) // episode_len)
    return rb


def scoring(online_td: bool = False) -> ScoringState:
    return ScoringState(CAP, K, teacher_agents=np.arange(N), icm_agents=np.arange(N), online_td=online_td)


def score(state: ScoringState, rb: ReplayBuffer, slots, stamp: int, folds=range(K)) -> None:
    """Every scorer scores `slots` at learner update `stamp`."""
    slots = np.asarray(slots, np.int64)
    gens = rb.generations(slots)
    errors = np.ones((slots.size, N, len(folds)), np.float32)
    state.write_difficulty(rb, slots, gens, folds, errors, stamp)
    state.write_curiosity(rb, slots, gens, np.ones((slots.size, N), np.float32), stamp)
    if state.online_td:
        state.write_online_td(rb, slots, gens, np.ones((slots.size, N), np.float32), stamp)


def test_oldest_first_never_scored_then_oldest():
    stamps = np.array([5.0, -1.0, 2.0, 9.0, -1.0, 2.5])
    assert oldest_first(np.arange(6), stamps, 3).tolist() == [1, 2, 4]
    assert oldest_first(np.arange(6), stamps, 10).tolist() == list(range(6))


def test_a_call_scores_never_scored_rows_first_then_the_oldest_scores():
    """A teacher group's or the ICM's call: a fixed number of rows (service.score_rows_per_call), never-scored ones
    first, then the oldest scores."""
    rb, state = buffer_with(20), scoring()
    everyone = {"folds": range(K), "curiosity": True}
    assert state.rows_to_score(rb, 4, **everyone).size == 4, "the count, never-scored rows or not"
    for stamp, rows in enumerate((range(0, 5), range(5, 10), range(10, 15), range(15, 20))):
        score(state, rb, rows, stamp)
    four = state.rows_to_score(rb, 4, **everyone)
    assert four.size == 4 and set(four) <= set(range(5))
    seven = state.rows_to_score(rb, 7, **everyone).tolist()
    assert seven[:5] == [0, 1, 2, 3, 4] and set(seven[5:]) <= set(range(5, 10))
    rb.add(*(np.zeros((3, N, 1), np.float32),) * 2, np.zeros((3, N), np.float32), np.zeros((3, N, 1), np.float32),
           np.zeros(3, np.float32), np.full(3, 9))  # slots 20..22: never scored, taken first
    picked = state.rows_to_score(rb, 4, **everyone).tolist()  # sorted by slot
    assert len(picked) == 4 and {20, 21, 22} <= set(picked) and picked[0] in range(5)


def test_the_learners_online_scores_take_every_never_scored_row_beyond_the_count():
    """A11 for ACL td_self's |δ| (the scorer the learner hosts): every never-scored row, then the oldest up to the
    count."""
    rb, state = buffer_with(20), scoring(online_td=True)
    assert state.rows_to_score(rb, 4, online_td=True, every_unscored=True).tolist() == list(range(20))
    slots = np.arange(20)
    state.write_online_td(rb, slots[:15], rb.generations(slots[:15]), np.ones((15, N), np.float32), 3)
    assert state.rows_to_score(rb, 7, online_td=True, every_unscored=True).size == 7
    assert set(state.rows_to_score(rb, 7, online_td=True, every_unscored=True)) >= set(range(15, 20))
    assert state.rows_to_score(rb, 2, online_td=True, every_unscored=True).tolist() == list(range(15, 20))


def test_rows_wait_for_the_oldest_score_of_every_scorer_asked():
    rb, state = buffer_with(10), scoring(online_td=True)
    score(state, rb, range(10), 7)
    slots, gens = np.arange(10), rb.generations(np.arange(10))
    state.write_curiosity(rb, slots[5:], gens[5:], np.ones((5, N), np.float32), 9)  # only ρ refreshed for 5..9
    assert state.rows_to_score(rb, 5, folds=range(K), curiosity=True, online_td=True).tolist() == [0, 1, 2, 3, 4]
    assert state.rows_to_score(rb, 5, curiosity=True).tolist() == [0, 1, 2, 3, 4]


def test_a_teacher_group_never_gets_rows_of_its_own_fold():
    rb, state = buffer_with(30), scoring()
    fold = rb.storage.fold[:30]
    rows = state.rows_to_score(rb, 30, folds=[1])
    assert rows.size == (fold != 1).sum() and (fold[rows] != 1).all()
    score(state, rb, rows[:6], 3, folds=[1])
    assert not set(state.rows_to_score(rb, 5, folds=[1])) & set(rows[:6]), "unscored rows of the group come first"


def test_overwritten_rows_count_as_never_scored():
    rb, state = buffer_with(30), scoring()
    score(state, rb, range(30), 1)
    everyone = {"folds": range(K), "curiosity": True, "every_unscored": True}
    assert state.rows_to_score(rb, 0, **everyone).size == 0
    z = np.zeros((5, N, 1), np.float32)
    rb.add(z, z, np.zeros((5, N), np.float32), z, np.zeros(5, np.float32), np.full(5, 50))  # overwrites 0..4
    assert state.rows_to_score(rb, 0, **everyone).tolist() == [0, 1, 2, 3, 4]
    assert state.rows_to_score(rb, 5, folds=range(K)).tolist() == [0, 1, 2, 3, 4]


def test_state_round_trip_and_a_snapshot_of_another_capacity_is_refused():
    rb, state = buffer_with(20), scoring()
    score(state, rb, range(10), 4)
    state.inserted(np.arange(20), 3)
    other = scoring()
    other.load_state_dict(state.state_dict())
    assert np.array_equal(other.rows_to_score(rb, 25), state.rows_to_score(rb, 25))
    assert np.array_equal(other.inserted_at, state.inserted_at)
    with pytest.raises(ValueError, match="inserted_at"):
        other.load_state_dict({**state.state_dict(), "inserted_at": np.zeros(3)})

"""cmcl/replay/ratelimit.py: the ratio of samples to inserts is held within ±slack under any interleaving."""

import numpy as np
import pytest

from cmcl.replay.ratelimit import RateLimiter, slack_for

TOL = 1e-6


@pytest.mark.parametrize("seed", range(6))
def test_ratio_held_within_slack_under_random_interleavings(seed):
    rng = np.random.default_rng(seed)
    ratio = float(rng.choice([0.25, 0.5, 1.0, 2.0, 3.5, 0.1]))
    warmup = int(rng.integers(0, 50))
    start = int(rng.integers(max(0, warmup - 10), warmup + 1))  # the target may count from before the warm-up
    max_chunk = int(rng.integers(1, 6))
    slack = max(slack_for(ratio, insert_chunk=max_chunk, sample_chunk=max_chunk),
                ratio * (warmup - start)) + float(rng.uniform(0, 3))
    lim = RateLimiter(ratio, warmup=warmup, slack=slack, start=start)
    p_insert = rng.uniform(0.1, 0.9)  # one side may be much faster than the other
    granted = {"insert": 0, "sample": 0}
    for _ in range(3000):
        assert lim.allowed_inserts() >= 1 or lim.allowed_samples() >= 1, f"deadlock at {lim!r}"
        n = int(rng.integers(1, max_chunk + 1))
        if rng.random() < p_insert:
            assert lim.can_insert(n) == (n <= lim.allowed_inserts())
            if lim.can_insert(n):
                lim.record_insert(n)
                granted["insert"] += 1
        else:
            assert lim.can_sample(n) == (n <= lim.allowed_samples())
            if lim.can_sample(n):
                lim.record_sample(n)
                granted["sample"] += 1
        if lim.inserts < warmup:
            assert lim.samples == 0
        else:
            target = ratio * (lim.inserts - start)
            assert target - slack - TOL <= lim.samples <= target + slack + TOL, repr(lim)
    assert granted["insert"] > 0 and granted["sample"] > 0
    assert lim.inserts > warmup  # both sides kept moving past the warm-up


def test_warmup_blocks_sampling_then_allows_the_ratio():
    lim = RateLimiter(1.0, warmup=10, slack=2)
    assert lim.allowed_samples() == 0 and not lim.can_sample()
    assert lim.allowed_inserts() == 12  # the whole warm-up plus `slack` samples' worth
    lim.record_insert(9)
    assert not lim.can_sample() and not lim.warmed_up
    lim.record_insert(1)
    assert lim.warmed_up and lim.allowed_samples() == 2  # samples may lead the target by slack
    lim.record_insert(2)
    assert not lim.can_insert()  # inserts 2 samples' worth ahead: held
    assert lim.allowed_samples() == 4
    lim.record_sample(4)
    assert not lim.can_sample() and lim.allowed_inserts() == 4 and lim.deficit == -2


def test_due_is_the_exact_owed_count():
    lim = RateLimiter(0.5, slack=1)  # e.g. teacher steps per learner update
    owed = []
    for _ in range(7):
        lim.record_insert(1)
        owed.append(lim.due())
        lim.record_sample(owed[-1])
    assert owed == [0, 1, 0, 1, 0, 1, 0] and lim.samples == 3  # floor(0.5 · 7)
    late = RateLimiter(1 / 16, warmup=800, slack=1, start=784)  # warm at 800, target counted from 784
    late.record_insert(799)
    assert late.due() == 0 and late.deficit == 15 / 16
    late.record_insert(1)
    assert late.due() == 1  # step 800 is a multiple of 16: due as soon as warm
    odd = RateLimiter(1 / 49, slack=1)
    odd.record_insert(49)
    assert odd.due() == 1  # (1 / 49) · 49 == 0.9999999999999999 still owes the step


def test_fractional_ratio_counts_exactly():
    lim = RateLimiter(0.1, warmup=0, slack=0.7)  # one update per 10 env steps
    assert lim.allowed_inserts() == 7  # 0.7 / 0.1 == 6.999999999999999 must still allow 7
    lim.record_insert(7)
    assert lim.allowed_samples() == 1 and lim.allowed_inserts() == 0
    lim.record_sample(1)
    assert lim.allowed_samples() == 0 and lim.allowed_inserts() == 10


def test_over_recording_is_caught_up_not_refused():
    lim = RateLimiter(1.0, slack=1)
    lim.record_insert(100)  # e.g. chunks accepted while the learner was down
    assert lim.allowed_inserts() == 0 and lim.allowed_samples() == 101
    lim.record_sample(101)
    assert lim.can_insert()


def test_state_round_trip():
    lim = RateLimiter(2.0, warmup=5, slack=3)
    lim.record_insert(9)
    lim.record_sample(7)
    state = lim.state_dict()
    assert all(type(v) in (int, float) for v in state.values())
    other = RateLimiter(2.0, warmup=5, slack=3)
    other.load_state_dict(dict(state))
    assert other.state_dict() == state
    assert (other.allowed_inserts(), other.allowed_samples()) == (lim.allowed_inserts(), lim.allowed_samples())
    with pytest.raises(ValueError, match="ratio=2.0, this limiter has ratio=1.0"):
        RateLimiter(1.0, warmup=5, slack=3).load_state_dict(state)
    with pytest.raises(ValueError, match="^rate limiter state without 'samples': written by an older version; "):
        other.load_state_dict({k: v for k, v in state.items() if k != "samples"})
    with pytest.raises(ValueError, match="inserts must be an integer >= 0, got -1"):
        other.load_state_dict({**state, "inserts": -1})
    with pytest.raises(ValueError, match="^rate limiter state without 'start': written by an older version; "):
        other.load_state_dict({k: v for k, v in state.items() if k != "start"})
    with pytest.raises(ValueError, match="start=5, this limiter has start=4"):
        RateLimiter(2.0, warmup=5, slack=3, start=4).load_state_dict(state)


@pytest.mark.parametrize("kwargs, words", [
    ({"ratio": 0}, "ratio must be a finite number > 0, got ratio=0"),
    ({"ratio": -1.5}, "got ratio=-1.5"),
    ({"ratio": float("nan")}, "got ratio=nan"),
    ({"ratio": True}, "got ratio=True"),
    ({"ratio": 1.0, "slack": -1}, "slack must be a finite number >= 0, got slack=-1"),
    ({"ratio": 1.0, "slack": 0.5}, "slack must be >= max((1 + ratio) / 2, ratio * (warmup - start)) = 1 so that"),
    ({"ratio": 0.5, "warmup": 10, "start": 2, "slack": 3}, "= 4 so that an insert or a sample is always allowed"),
    ({"ratio": 1.0, "warmup": 3, "start": 4}, "start must be <= warmup (3), got start=4"),
    ({"ratio": 1.0, "warmup": 3, "start": -1}, "start must be an integer >= 0, got -1"),
    ({"ratio": 1.0, "warmup": -3}, "warmup must be an integer >= 0, got -3"),
    ({"ratio": 1.0, "warmup": 2.5}, "warmup must be an integer >= 0, got 2.5"),
])
def test_bad_arguments_raise_naming_argument_and_value(kwargs, words):
    with pytest.raises(ValueError) as info:
        RateLimiter(**kwargs)
    assert words in str(info.value)


def test_bad_counts_raise():
    lim = RateLimiter(1.0)
    for call in (lim.record_insert, lim.record_sample, lim.can_insert, lim.can_sample):
        with pytest.raises(ValueError, match="n must be an integer >= 0, got -1"):
            call(-1)

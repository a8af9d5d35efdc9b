"""cmcl/replay/ratelimit.py: the ratio of samples to inserts is held within ±slack under any interleaving."""

import numpy as np
import pytest

from cmcl.config import preset
from cmcl.replay.ratelimit import RateLimiter, limiters_from_config, slack_for

TOL = 1e-6


@pytest.mark.parametrize("seed", range(6))
def test_ratio_held_within_slack_under_random_interleavings(seed):
    rng = np.random.default_rng(seed)
    ratio = float(rng.choice([0.25, 0.5, 1.0, 2.0, 3.5, 0.1]))
    warmup = int(rng.integers(0, 50))
    max_chunk = int(rng.integers(1, 6))
    slack = slack_for(ratio, insert_chunk=max_chunk, sample_chunk=max_chunk) + float(rng.uniform(0, 3))
    lim = RateLimiter(ratio, warmup=warmup, slack=slack)
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
            target = ratio * (lim.inserts - warmup)
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
    with pytest.raises(ValueError, match="lacks key 'samples'"):
        other.load_state_dict({k: v for k, v in state.items() if k != "samples"})
    with pytest.raises(ValueError, match="inserts must be an integer >= 0, got -1"):
        other.load_state_dict({**state, "inserts": -1})


@pytest.mark.parametrize("kwargs, words", [
    ({"ratio": 0}, "ratio must be a finite number > 0, got ratio=0"),
    ({"ratio": -1.5}, "got ratio=-1.5"),
    ({"ratio": float("nan")}, "got ratio=nan"),
    ({"ratio": True}, "got ratio=True"),
    ({"ratio": 1.0, "slack": -1}, "slack must be a finite number >= 0, got slack=-1"),
    ({"ratio": 1.0, "slack": 0.5}, "slack must be >= (1 + ratio) / 2 = 1 so that"),
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


def test_limiters_from_config():
    cmcl = limiters_from_config(preset("cmcl"), insert_chunk=16)
    assert len(cmcl.teachers) == preset("cmcl").teachers.num_folds and cmcl.icm is not None
    learner = cmcl.learner
    every = preset("cmcl").maddpg.update_every  # world steps per update
    assert learner.ratio == 1.0 / every and learner.warmup == 3840
    assert learner.slack == max((1 + 1 / every) / 2, 16 / every, 1.0)  # a 16-transition chunk always fits
    learner.record_insert(3840)
    assert learner.can_insert(16)  # a whole chunk fits at the end of warm-up
    maddpg, acl = limiters_from_config(preset("maddpg")), limiters_from_config(preset("acl"))
    assert (maddpg.teachers, maddpg.icm) == ([], None) and acl.teachers and acl.icm is None


def test_the_service_slack_widens_every_limiter_as_the_replay_server_needs():
    plain = limiters_from_config(preset("cmcl"), insert_chunk=480, fit_chunk=8)
    service = limiters_from_config(preset("cmcl"), insert_chunk=480, fit_chunk=8, extra_slack=256)
    assert service.learner.slack == max(plain.learner.slack, 256.0)
    assert [t.slack for t in service.teachers] == [t.slack + 256 for t in plain.teachers]
    assert service.icm.slack == plain.icm.slack + 256
    assert plain.teachers[0].slack >= 8  # a call's 8 fit steps can always be granted

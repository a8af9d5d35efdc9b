"""λ schedule (ALGORITHM.md §3.7, §7 property 21)."""

import pytest

from cmcl.replay.curriculum import CurriculumSchedule, default_growth, default_stride

T = 600_000  # 20 000 episodes × 30 steps


def test_default_stride_matches_spec():
    assert default_stride(T) == pytest.approx(3e-6, rel=1e-12)
    assert default_stride(1000, lam0=0.2, lam_max=0.8) == pytest.approx(0.6 / 500)
    with pytest.raises(ValueError, match="total_env_steps"):
        default_stride(0)


def test_linear_schedule_property_21():
    sch = CurriculumSchedule(stride=default_stride(T), warmup_steps=3840)
    assert sch.lam == 0.1
    sch.advance(3840)  # warm-up: λ does not move
    assert sch.lam == 0.1
    prev = sch.lam
    for _ in range(1000):
        lam = sch.advance(1)
        assert lam - prev == pytest.approx(3e-6, abs=1e-15)
        prev = lam
    sch.advance(T // 2 - 1000)
    assert sch.t_learn == T // 2
    assert sch.lam == pytest.approx(1.0, abs=1e-12)
    sch.advance(10 * T)
    assert sch.lam == 1.0
    assert all(sch.value(t) <= 1.0 for t in (0, T, 10 * T, 1e30))


def test_multiplicative_schedule():
    growth = default_growth(T)
    sch = CurriculumSchedule(kind="multiplicative", growth=growth, warmup_steps=0)
    assert sch.value(0) == 0.1
    assert sch.value(1) == pytest.approx(0.1 * (1 + growth))
    assert sch.value(T // 2) == pytest.approx(1.0, rel=1e-9)
    assert sch.value(1e18) == 1.0  # log-space, no overflow
    vals = [sch.value(t) for t in range(0, T, 10_000)]
    assert all(b >= a for a, b in zip(vals, vals[1:], strict=False))


def test_state_dict_round_trip_and_validation():
    sch = CurriculumSchedule(warmup_steps=10)
    sch.advance(12345)
    other = CurriculumSchedule(warmup_steps=10)
    other.load_state_dict(sch.state_dict())
    assert other.lam == sch.lam and other.env_steps == 12345
    with pytest.raises(ValueError, match="stride"):
        CurriculumSchedule(stride=1e-5, warmup_steps=10).load_state_dict(sch.state_dict())
    with pytest.raises(ValueError, match="env_steps"):
        other.load_state_dict({"env_steps": -3})
    assert other.env_steps == 12345

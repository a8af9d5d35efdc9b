"""cmcl.run.stalls: the final-step anatomy of missed landmarks and the plateau measure, on hand-built worlds."""

import numpy as np
import pytest

from cmcl.run.stalls import MISS_CLASSES, MissAnatomy, miss_anatomy, moving_average, plateau_episodes

LANDMARKS = np.array([[[-0.3, -0.3], [0.3, -0.3], [-0.3, 0.3], [0.3, 0.3]]])  # [1, 4, 2]
R, AGENT_R = 0.1, 0.05


def world(agents):
    return np.asarray([agents], dtype=np.float64), LANDMARKS


def test_every_landmark_covered_misses_nothing():
    a = miss_anatomy(*world(LANDMARKS[0] + 0.01), R, AGENT_R)
    assert a.missed_share == 0 and a.agent_idle_share == [0.0] * 4
    assert set(a.missed_by_class) == set(MISS_CLASSES) and sum(a.missed_by_class.values()) == 0


@pytest.mark.parametrize("last_agent, expected", [
    ([0.3, -0.3], "crowded"),   # on landmark 1 with agent 1
    ([0.3, 0.15], "short"),     # 0.15 from landmark 3 (within 2 radii), on none
    ([0.0, 0.0], "far"),        # 0.42 from landmark 3
])
def test_a_missed_landmark_is_classed_by_what_the_agents_do(last_agent, expected):
    agents = [LANDMARKS[0][0], LANDMARKS[0][1], LANDMARKS[0][2], last_agent]
    a = miss_anatomy(*world(agents), R, AGENT_R)
    assert a.missed_share == 1
    assert a.missed_by_class[expected] == 1 and sum(a.missed_by_class.values()) == 1
    if expected == "crowded":
        assert a.agent_crowding_share == [0.0, 1.0, 0.0, 1.0] and a.agent_idle_share == [0.0] * 4
    else:
        assert a.agent_idle_share == [0.0, 0.0, 0.0, 1.0]


def test_an_agent_pinned_to_a_wall_is_counted_and_shares_average_over_worlds():
    covered = LANDMARKS[0] + 0.01
    pinned = np.array([covered[0], covered[1], covered[2], [0.45, 0.0]])  # x = ARENA_HALF - radius
    pos = np.stack([covered, pinned])
    a = miss_anatomy(pos, np.repeat(LANDMARKS, 2, axis=0), R, AGENT_R)
    assert a.worlds == 2 and a.missed_share == 0.5
    assert a.agent_wall_share == [0.0, 0.0, 0.0, 0.5] and a.agent_idle_share == [0.0, 0.0, 0.0, 0.5]
    assert a.idle_distance_median == pytest.approx(np.hypot(0.15, 0.3))
    assert any("at a wall" in line for line in a.lines())


def test_shapes_are_checked():
    with pytest.raises(ValueError, match=r"\[B, N, 2\]"):
        miss_anatomy(np.zeros((2, 4, 2)), np.zeros((1, 4, 2)), R, AGENT_R)


def test_plateau_counts_episodes_whose_moving_average_sits_in_the_band():
    coverage = np.concatenate([np.zeros(300), np.full(500, 0.75), np.ones(300)])
    ma = moving_average(coverage, 100)
    assert ma[299] == 0 and ma[399] == pytest.approx(0.75) and ma[-1] == 1
    expected = int(((ma >= 0.65) & (ma <= 0.85)).sum())
    assert plateau_episodes(coverage) == expected
    assert 400 <= expected < 500  # the 500 plateau episodes, less the ramps in and out of the window
    with pytest.raises(ValueError, match="low=0.9"):
        plateau_episodes(coverage, low=0.9, high=0.8)


def test_a_world_whose_landmarks_one_agent_covers_two_of_is_covered_but_unmatched():
    close = np.array([[[-0.3, -0.3], [0.3, -0.3], [-0.3, 0.3], [-0.3, 0.42]]])  # landmarks 2 and 3 0.12 apart
    between = [-0.3, 0.36]  # within 0.1 of both
    idle = miss_anatomy(np.array([[close[0][0], close[0][1], between, [0.0, 0.0]]]), close, R, AGENT_R)
    assert idle.missed_share == 0 and idle.covered_unmatched_share == 1 and idle.unmatched_idle_share == 1
    assert "one agent on two): 100.0 % of 1; of those, with an agent on no landmark 100.0 %" in "\n".join(idle.lines())
    shared = miss_anatomy(np.array([[close[0][0], close[0][1], between, close[0][1]]]), close, R, AGENT_R)
    assert shared.covered_unmatched_share == 1 and shared.unmatched_idle_share == 0
    own = miss_anatomy(np.array([[close[0][0], close[0][1], close[0][2], close[0][3]]]), close, R, AGENT_R)
    assert own.covered_unmatched_share == 0 and own.unmatched_idle_share == 0


def test_an_anatomy_stored_before_the_unmatched_worlds_were_measured_prints_without_them():
    stored = {k: v for k, v in vars(miss_anatomy(*world(LANDMARKS[0] + 0.01), R, AGENT_R)).items()
              if k not in ("covered_unmatched_share", "unmatched_idle_share")}
    assert not any("every landmark covered" in line for line in MissAnatomy(**stored).lines())

"""The own-environment table (lab.report.own_env_table): one row per environment, runner and team, the held-out
return's mean ± sd over the seeds beside the random policy's, and the team against random others for competing
teams only."""

from lab.report.own_env_table import own_env_table


def summary(seed: int, adversary: float, agent: float, wall_s: float) -> dict:
    return {"env": "tag", "mode": "service", "seed": seed, "episodes": 8, "wall_s": wall_s,
            "held_out_return": {"adversary": adversary, "agent": agent},
            "random_return": {"adversary": 1.0, "agent": -2.0},
            "vs_random_others_return": {"adversary": 3.0, "agent": -1.0}}


def test_a_competing_env_gets_a_row_per_team_with_its_return_against_random_others():
    lines = own_env_table([summary(0, 5.0, -4.0, 10.0), summary(1, 7.0, -6.0, 12.0)]).splitlines()
    assert len(lines) == 4
    assert lines[2].startswith("| mpe2 simple_tag_v3 | service | adversary | 6.0 ± 1.4 | 1.0 ± 0.0 | 3.0 ± 0.0 |")
    assert lines[3].split(" | ")[2] == "agent" and lines[3].endswith(" | 0,1 | 8 | 11 |")

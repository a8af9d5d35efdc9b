"""The sampling part of both runners' progress lines (cmcl.progress.sampling_parts, its inline and service callers):
ESS and the reward rows sampled against the buffer, averaged over the agents that do not sample uniformly."""

from cmcl.messages import ReplayStatus
from cmcl.progress import row_sampling_parts, sampling_parts
from services.progress_view import replay_parts
from services.report_schema import ReplayReport, Report


def test_the_part_averages_over_the_agents_that_do_not_sample_uniformly():
    parts = sampling_parts([1.0, 0.3, 0.5], [0.25, 0.01, 0.03], [0.25, 0.2, 0.1], [True, False, False])
    assert parts == ["ESS 0.40", "reward rows 0.02/0.15"]


def test_every_agent_uniform_shows_nothing_and_missing_shares_show_the_ess_alone():
    assert sampling_parts([1.0, 1.0], [0.2, 0.2], [0.2, 0.2], [True, True]) == []
    assert sampling_parts([0.5], [], [], [False]) == ["ESS 0.50"]


def test_an_inline_progress_row_reads_its_modes_and_shares():
    row = {"sampling": {"ess_fraction": [0.28, 1.0], "modes": ["curriculum", "uniform"],
                        "reward_rows_sampled": [0.02, 0.3], "reward_rows_buffer": [0.18, 0.3]}}
    assert row_sampling_parts(row) == ["ESS 0.28", "reward rows 0.02/0.18"]
    assert row_sampling_parts({}) == []


def test_the_service_line_shows_the_same_parts_from_the_replay_report():
    status = ReplayStatus(allowed_updates=0, allowed_inserts=0, update_deficit=0.0, scoring_deficit=0.0,
                          teacher_allowed=(), icm_allowed=0, size=500, env_steps=900, episodes=30, updates=40,
                          lam=0.2, incarnation="x")
    replay = ReplayReport(agent_sampling_ess={"0": 0.3, "1": 0.5}, reward_rows_sampled={"0": 0.01, "1": 0.03},
                          reward_rows_buffer={"0": 0.2, "1": 0.1})
    parts = replay_parts(status, Report(replay=replay), {})
    assert parts == ["buf 500", "ESS 0.40", "reward rows 0.02/0.15"]
    uniform = ReplayReport(agent_sampling_ess={"0": 1.0}, reward_rows_sampled={"0": 0.2}, reward_rows_buffer={"0": 0.2})
    assert replay_parts(status, Report(replay=uniform), {}) == ["buf 500"]

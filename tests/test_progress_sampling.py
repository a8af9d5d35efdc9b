"""The sampling part of both runners' progress lines (cmcl.progress.rows.sampling_parts, its inline and service
callers): ESS and the reward rows sampled against the buffer, averaged over the agents that do not sample uniformly."""

import pytest

from cmcl.progress.rows import row_sampling_parts, sampling_parts
from cmcl.replay.messages import ReplayStatus
from services.observability.progress_view import replay_parts
from services.observability.report_schema import ReplayReport, Report


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
                          teacher_allowed=(), icm_allowed=0, updates_held_by="env_steps", size=500, env_steps=900,
                          episodes=30, updates=40, lam=0.2, incarnation="x")
    replay = ReplayReport(agent_sampling_ess={"0": 0.3, "1": 0.5}, reward_rows_sampled={"0": 0.01, "1": 0.03},
                          reward_rows_buffer={"0": 0.2, "1": 0.1})
    parts = replay_parts(status, Report(replay=replay), {})
    assert parts == ["buf 500", "ESS 0.40", "reward rows 0.02/0.15"]
    uniform = ReplayReport(agent_sampling_ess={"0": 1.0}, reward_rows_sampled={"0": 0.2}, reward_rows_buffer={"0": 0.2})
    assert replay_parts(status, Report(replay=uniform), {}) == ["buf 500"]


def test_the_service_progress_row_carries_the_sampling_entry_in_the_inline_rows_shape():
    from experiments.measures import sampling_over_training
    from services.observability.progress_view import sampling_row

    replay = ReplayReport(agent_sampling_ess={"1": 0.5, "0": 1.0}, reward_rows_sampled={"0": 0.2, "1": 0.01},
                          reward_rows_buffer={"0": 0.2, "1": 0.1}, kp_branches={"rising": 0.5, "falling": 0.3,
                                                                                 "excluded": 0.2},
                          score_coverage=0.9)
    row = sampling_row(Report(replay=replay), ["uniform", "cmcl"])
    assert row == {"sampling": {"modes": ["uniform", "cmcl"], "ess_fraction": [1.0, 0.5],
                                "reward_rows_sampled": [0.2, 0.01], "reward_rows_buffer": [0.2, 0.1]},
                   "kp_branches": {"rising": 0.5, "falling": 0.3, "excluded": 0.2}, "score_coverage": 0.9}
    curve = sampling_over_training([{"episodes": 100, "lambda": 0.2, **row}])["sampling_curve"]
    assert curve["ess"] == [0.5] and curve["reward_rows_sampled"] == [0.01]  # the cmcl agent's, as inline
    assert sampling_row(None, ["cmcl"]) == {} and sampling_row(Report(replay=ReplayReport(size=3)), ["cmcl"]) == {}
    assert sampling_row(Report(replay=replay), ["cmcl"]) == {}  # a report of another agent count is not mixed in


def test_sampling_name_is_the_name_of_the_distribution_the_registry_builds():
    from cmcl.replay.registry import ALGORITHMS, build_sampler, sampling_name
    from cmcl.replay.sampling import SamplerArgs

    for algorithm in ALGORITHMS:
        built = build_sampler(algorithm, SamplerArgs(capacity=8, alpha=1.0, backend="cdf", eps=1e-3, eta=0.5))
        assert sampling_name(algorithm) == built.name
    with pytest.raises(ValueError, match="'ddpg'"):
        sampling_name("ddpg")


def test_the_service_line_says_what_is_owed_once_every_episode_is_collected():
    """After the last episode the run waits for the learner and the scorers to reach their ratios: the line says so
    instead of "left ~0s"."""
    from dataclasses import replace

    from cmcl.progress.clock import RunClock
    from services.observability.progress_view import ProgressView

    status = ReplayStatus(allowed_updates=0, allowed_inserts=0, update_deficit=373.4, scoring_deficit=45.0,
                          teacher_allowed=(), icm_allowed=0, updates_held_by="env_steps", size=500, env_steps=900,
                          episodes=30, updates=40, lam=0.2, incarnation="x")
    view = ProgressView(30, RunClock(started=0.0), status, ["curriculum"])
    line = view.line(status, None, {}, [])
    assert line.endswith("| finishing: 373 updates, 45 teacher / ICM fit steps owed") and "left ~" not in line, line
    assert view.line(replace(status, update_deficit=0.5), None, {}, []).endswith("45 teacher / ICM fit steps owed")
    assert "finishing" not in view.line(replace(status, update_deficit=0.0, scoring_deficit=0.0), None, {}, [])
    assert "finishing" not in view.line(replace(status, episodes=29), None, {}, [])

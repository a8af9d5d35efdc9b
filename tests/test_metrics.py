"""services/observability/metrics.py: the one Prometheus endpoint, fed by actor reports (no Ray needed).

Every test that serves HTTP shuts its server down; values are read back over HTTP or from the exposition text
and parsed with prometheus-client's own parser.
"""

import math
import urllib.request

import numpy as np
import pytest
from prometheus_client.parser import text_string_to_metric_families

from services.observability.metrics import DEFAULT_MAX_SAMPLES, HISTOGRAMS, ServiceMetrics
from services.observability.report_schema import (
    CurriculumReport,
    FinishedEpisodes,
    FitReport,
    LearnerReport,
    ReplayReport,
    Report,
    RolloutReport,
)

REQUIRED = {
    "cmcl_replay_size", "cmcl_replay_capacity", "cmcl_replay_inserts_total", "cmcl_replay_samples_total",
    "cmcl_replay_rejected_total", "cmcl_curriculum_lambda", "cmcl_difficulty", "cmcl_priority",
    "cmcl_kfold_priority", "cmcl_curiosity_priority", "cmcl_teacher_scores_total",
    "cmcl_teacher_score_age_updates", "cmcl_teacher_score_coverage", "cmcl_curiosity_scores_total",
    "cmcl_icm_loss", "cmcl_learner_updates_total", "cmcl_learner_loss", "cmcl_weight_version_lag",
    "cmcl_env_steps_total", "cmcl_episodes_total", "cmcl_coverage_rate", "cmcl_success_rate", "cmcl_win_rate",
    "cmcl_episode_reward", "cmcl_actor_restarts_total", "cmcl_updates_per_second", "cmcl_env_steps_per_second",
    "cmcl_intrinsic_reward",
}


def samples(text: str) -> dict[tuple[str, frozenset], float]:
    """{(sample name, labels): value} of an exposition text."""
    out = {}
    for family in text_string_to_metric_families(text):
        for s in family.samples:
            out[(s.name, frozenset(s.labels.items()))] = s.value
    return out


def get(parsed: dict, name: str, **labels: str) -> float:
    return parsed[(name, frozenset(labels.items()))]


@pytest.fixture
def served():
    """A ServiceMetrics serving on 127.0.0.1 with a free port; shut down afterwards."""
    metrics = ServiceMetrics()
    port = metrics.serve(0)
    try:
        yield metrics, port
    finally:
        metrics.close()


def scrape(port: int) -> dict:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10) as response:
        assert response.status == 200
        return samples(response.read().decode("utf-8"))


def test_defines_every_required_metric():
    assert REQUIRED <= ServiceMetrics().metric_names()


def test_endpoint_binds_loopback_and_picks_a_free_port(served):
    metrics, port = served
    assert port > 0
    assert metrics.address == ("127.0.0.1", port)
    with pytest.raises(RuntimeError, match="already serving"):
        metrics.serve(0)


def test_reports_reach_the_endpoint(served):
    metrics, port = served
    metrics.apply(Report(source="replay", role="replay", incarnation="r1",
                         replay=ReplayReport(size=300, capacity=5000, inserts=300, samples=128,
                                             rejected={"bad_shape": 2, "non_finite": 1}, score_coverage=0.25,
                                             difficulty=np.array([0.0, 0.04, 0.05, 0.5, 1.0, 3.0])),
                         curriculum=CurriculumReport(lam=0.125)))
    metrics.apply(Report(source="learner", role="learner", learner=LearnerReport(
        updates=7, weight_version=9, losses={"agent_0": {"critic": 0.5, "actor": -1.25}}, intrinsic_reward=0.375)))
    metrics.apply(Report(source="rollout-0", role="rollout", weight_version=6,
                         rollout=RolloutReport(env_steps=480, episodes=16, finished=FinishedEpisodes(
                             coverage=[0.25, 0.75], success=[0, 1], reward={"agent": [-10.0, -4.0]}))))
    metrics.apply(Report(source="teacher-1", role="teacher",
                         teachers={"1": FitReport(steps=3, scores=900, loss=0.1)}))
    metrics.apply(Report(source="icm", role="icm", icm=FitReport(steps=4, scores=1200, loss=0.75)))
    p = scrape(port)
    assert get(p, "cmcl_replay_size") == 300 and get(p, "cmcl_replay_capacity") == 5000
    assert get(p, "cmcl_replay_inserts_total") == 300 and get(p, "cmcl_replay_samples_total") == 128
    assert get(p, "cmcl_replay_rejected_total", reason="bad_shape") == 2
    assert get(p, "cmcl_replay_rejected_total", reason="non_finite") == 1
    assert get(p, "cmcl_curriculum_lambda") == 0.125 and get(p, "cmcl_teacher_score_coverage") == 0.25
    # le semantics: 0.0 and 0.04 <= 0.05, 0.05 <= 0.05; 3.0 only in +Inf.
    assert get(p, "cmcl_difficulty_bucket", le="0.05") == 3
    assert get(p, "cmcl_difficulty_bucket", le="0.5") == 4
    assert get(p, "cmcl_difficulty_bucket", le="1.0") == 5
    assert get(p, "cmcl_difficulty_bucket", le="+Inf") == 6 and get(p, "cmcl_difficulty_count") == 6
    assert math.isclose(get(p, "cmcl_difficulty_sum"), 4.59)
    assert get(p, "cmcl_learner_updates_total") == 7
    assert get(p, "cmcl_learner_loss", agent="agent_0", kind="actor") == -1.25
    assert get(p, "cmcl_intrinsic_reward") == 0.375
    assert get(p, "cmcl_weight_version_lag", actor="rollout-0") == 3
    assert get(p, "cmcl_env_steps_total") == 480 and get(p, "cmcl_episodes_total") == 16
    assert get(p, "cmcl_coverage_rate") == 0.5 and get(p, "cmcl_success_rate") == 0.5
    assert get(p, "cmcl_episode_reward", team="agent") == -7.0
    assert get(p, "cmcl_teacher_scores_total", teacher="1") == 900
    assert get(p, "cmcl_teacher_steps_total", teacher="1") == 3
    assert get(p, "cmcl_curiosity_scores_total") == 1200 and get(p, "cmcl_icm_loss") == 0.75
    assert get(p, "cmcl_metrics_reports_total") == 5


def steps(metrics: ServiceMetrics) -> float:
    return samples(metrics.text())[("cmcl_env_steps_total", frozenset())]


def test_counter_delta_rule_across_restarts():
    m = ServiceMetrics()
    report = lambda total, **top: Report(source="w0", role="rollout", **top,  # noqa: E731
                                         rollout=RolloutReport(env_steps=total))
    m.apply(report(100, incarnation="a"))
    m.apply(report(150, incarnation="a"))
    m.apply(report(150, incarnation="a"))  # a repeated report adds nothing
    assert steps(m) == 150
    m.apply(report(120, incarnation="a"))  # an older report of the same process, applied late: no reset
    assert steps(m) == 150
    m.apply(report(20, incarnation="b"))  # restarted from zero: all 20 are new
    assert steps(m) == 170
    m.apply(report(200, incarnation="c"))  # restarted and already past the old total: still all new
    assert steps(m) == 370
    m.apply(report(150, incarnation="d", resumed=True))  # restored from a checkpoint below the last total
    assert steps(m) == 370
    m.apply(report(260, incarnation="d", resumed=True))  # only the part above 200 is new
    assert steps(m) == 430
    m.apply(report(10))  # no incarnation given: a lower total is a reset (Prometheus rule)
    assert steps(m) == 440
    parsed = samples(m.text())
    assert get(parsed, "cmcl_actor_restarts_total", role="rollout") == 3
    # Another source's totals are independent.
    m.apply(Report(source="w1", rollout=RolloutReport(env_steps=5)))
    assert steps(m) == 445


def test_every_labelled_counter_exports_each_label_value_from_the_start():
    parsed = samples(ServiceMetrics().text())  # no report applied yet
    for role in ("rollout", "replay", "learner", "teacher", "icm"):
        assert get(parsed, "cmcl_actor_restarts_total", role=role) == 0
        assert get(parsed, "cmcl_checkpoints_refused_total", role=role) == 0
    for reason in ("bad_chunk", "duplicate", "invalid", "bad_feedback", "bad_scores", "log_truncated"):
        assert get(parsed, "cmcl_replay_rejected_total", reason=reason) == 0
    assert get(parsed, "cmcl_replay_stale_scores_total") == 0


def test_stale_score_updates_have_their_own_counter_apart_from_rejected_input():
    m = ServiceMetrics()
    m.apply(Report(source="replay", role="replay", incarnation="a",
                   replay=ReplayReport(stale_scores=45_000, rejected={"bad_chunk": 2})))
    parsed = samples(m.text())
    assert get(parsed, "cmcl_replay_stale_scores_total") == 45_000
    assert get(parsed, "cmcl_replay_rejected_total", reason="bad_chunk") == 2
    assert sum(v for (name, _), v in parsed.items() if name == "cmcl_replay_rejected_total") == 2


def test_the_sampling_distribution_per_agent_reaches_the_endpoint():
    m = ServiceMetrics()
    m.apply(Report(source="replay", role="replay", replay=ReplayReport(
        agent_sampling_ess={"0": 0.31, "1": 1.0}, reward_rows_sampled={"0": 0.02, "1": 0.07},
        reward_rows_buffer={"0": 0.05, "1": 0.07})))
    parsed = samples(m.text())
    assert get(parsed, "cmcl_agent_sampling_ess_fraction", agent="0") == 0.31
    assert get(parsed, "cmcl_reward_rows_fraction", agent="0", where="sampled") == 0.02
    assert get(parsed, "cmcl_reward_rows_fraction", agent="0", where="buffer") == 0.05


def test_histograms_subsample_large_arrays():
    m = ServiceMetrics(max_samples=64, seed=1)
    m.apply(Report(replay=ReplayReport(priority=np.full(10_000, 1.2), score_age=np.arange(10),
                                       kfold_priority=np.zeros((4, 5)), curiosity_priority=[0.5])))
    p = samples(m.text())
    assert get(p, "cmcl_priority_count") == 64
    assert get(p, "cmcl_priority_bucket", le="1.1") == 0 and get(p, "cmcl_priority_bucket", le="1.2") == 64
    assert math.isclose(get(p, "cmcl_priority_sum"), 64 * 1.2)
    assert get(p, "cmcl_teacher_score_age_updates_count") == 10
    assert get(p, "cmcl_teacher_score_age_updates_bucket", le="2.0") == 3
    assert get(p, "cmcl_kfold_priority_count") == 20 and get(p, "cmcl_curiosity_priority_count") == 1
    assert DEFAULT_MAX_SAMPLES == ServiceMetrics().max_samples == 512


def test_rates_windows_and_lag_with_a_fake_clock():
    clock = [100.0]
    m = ServiceMetrics(window=3, rate_interval=10.0, clock=lambda: clock[0])
    m.apply(Report(source="w0", weight_version=2, rollout=RolloutReport(env_steps=0),
                   learner=LearnerReport(updates=0)))
    clock[0] = 104.0
    m.apply(Report(source="w0", rollout=RolloutReport(env_steps=400), learner=LearnerReport(updates=40)))
    assert m.value("cmcl_env_steps_per_second") == 0  # not refreshed before rate_interval elapsed
    clock[0] = 110.0
    m.apply(Report(source="w0", rollout=RolloutReport(env_steps=1000,
                                                      finished=FinishedEpisodes(win={"predator": [1, 1, 0, 0]}))))
    assert m.value("cmcl_env_steps_per_second") == 100.0 and m.value("cmcl_updates_per_second") == 4.0
    assert m.value("cmcl_win_rate", {"team": "predator"}) == pytest.approx(1 / 3)  # last 3 episodes
    m.update_rates(now=120.0)  # no growth since 110, but within the 30 s window: growth since 100 over 20 s
    assert m.value("cmcl_env_steps_per_second") == 50.0
    m.update_rates(now=141.0)  # the window [111, 141] saw no growth: base the mark of 110
    assert m.value("cmcl_env_steps_per_second") == 0.0
    m.apply(Report(source="learner", learner=LearnerReport(weight_version=5)))
    assert m.value("cmcl_weight_version_lag", {"actor": "w0"}) == 3
    m.apply(Report(source="w0", weight_version=5))
    assert m.value("cmcl_weight_version_lag", {"actor": "w0"}) == 0


def test_constructor_and_serve_arguments_are_checked():
    with pytest.raises(ValueError, match="max_samples must be >= 1, got 0"):
        ServiceMetrics(max_samples=0)
    with pytest.raises(ValueError, match="port must be an integer in \\[0, 65535\\], got 70000"):
        ServiceMetrics().serve(70000)


def test_a_learner_that_reports_less_often_than_the_refresh_never_reads_zero_while_it_trains():
    # the live dashboard's "Updates / s" read 0 at random on a loaded machine: the learner reports once per call of
    # 16 updates, a call took longer than the 5 s refresh, and the rate covered only the last refresh
    clock = [0.0]
    m = ServiceMetrics(rate_interval=5.0, clock=lambda: clock[0])  # the default window, 30 s
    updates, rates = 0, []
    for t in range(0, 120):  # a rollout report every second, a learner report every 8 s
        clock[0] = float(t)
        m.apply(Report(source="w0", rollout=RolloutReport(env_steps=100 * t)))
        if t % 8 == 0:
            updates += 16
            m.apply(Report(source="learner", learner=LearnerReport(updates=updates)))
        if t >= 10:
            rates.append(m.value("cmcl_updates_per_second"))
    assert min(rates) > 0 and max(rates) < 4, (min(rates), max(rates))  # 16 / 8 s = 2 per second
    clock[0] = 200.0  # the learner stopped: 30 s later the rate says so
    m.apply(Report(source="w0", rollout=RolloutReport(env_steps=100 * 200)))
    m.update_rates(now=240.0)
    assert m.value("cmcl_updates_per_second") == 0.0


def test_the_rate_window_must_hold_a_refresh():
    with pytest.raises(ValueError, match="rate_window"):
        ServiceMetrics(rate_interval=5.0, rate_window=1.0)


def test_a_report_as_a_mapping_omits_absent_fields_and_names_lambda_by_its_key():
    report = Report(teachers={"3": FitReport(steps=2)}, curriculum=CurriculumReport(lam=0.5))
    assert report.to_dict() == {"source": "default", "role": "unknown", "resumed": False,
                                "teachers": {"3": {"steps": 2}}, "curriculum": {"lambda": 0.5}}


def test_sample_keys_are_the_histograms_in_draw_order():
    from services.observability.report_schema import SAMPLE_KEYS

    assert tuple(HISTOGRAMS) == SAMPLE_KEYS

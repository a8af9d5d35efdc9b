"""services/observability/report_schema.py: the metrics report schema as dataclasses; parse_report validates, to_dict
inverts."""

import numpy as np
import pytest

from services.observability.metrics import HISTOGRAMS, ServiceMetrics
from services.observability.report_schema import (
    SAMPLE_KEYS,
    CurriculumReport,
    FitReport,
    Report,
    ReportError,
    RolloutReport,
    parse_report,
)

GOOD = {
    "schema": 1, "source": "rollout-0", "role": "rollout", "incarnation": "5f0c", "resumed": True,
    "weight_version": 12,
    "replay": {"size": 300.0, "capacity": 5000.0, "inserts": 300.0, "samples": 128.0,
               "rejected": {"bad_shape": 2.0}, "score_coverage": 0.25,
               "agent_sampling_ess": {"0": 0.5, "1": 1.0}, "reward_rows_sampled": {"0": 0.3, "1": 0.1},
               "reward_rows_buffer": {"0": 0.1, "1": 0.1},
               **{key: np.linspace(0, 1, 7) for key in SAMPLE_KEYS}},
    "curriculum": {"lambda": 0.125},
    "teachers": {"0": {"steps": 3.0, "scores": 900.0, "loss": 0.1}, "1": {"steps": 1.0}},
    "icm": {"steps": 4.0, "scores": 1200.0, "loss": 0.75},
    "learner": {"updates": 7.0, "weight_version": 9, "losses": {"agent_0": {"critic": 0.5, "actor": -1.25}}},
    "rollout": {"env_steps": 480.0, "episodes": 16.0,
                "finished": {"coverage": np.array([0.25, 0.75]), "success": np.array([0.0, 1.0]),
                             "reward": {"agent": np.array([-10.0, -4.0])}, "win": {"predator": np.array([1.0])}}},
}


def same(a, b) -> bool:
    """Nested equality of plain reports, arrays compared element-wise (and by dtype float64)."""
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return np.asarray(b).dtype == np.float64 and np.array_equal(a, b)
    return type(a) is type(b) and a == b


def test_a_good_report_round_trips():
    report = parse_report(GOOD)
    assert same(report.to_dict(), GOOD)
    assert same(parse_report(report.to_dict()).to_dict(), GOOD)
    assert report.curriculum.lam == 0.125 and report.teachers["1"] == FitReport(steps=1.0)
    assert report.learner.weight_version == 9 and isinstance(report.rollout.finished.reward["agent"], np.ndarray)


def test_defaults_and_normalisation():
    report = parse_report({"teachers": {3: {"steps": 2}}, "replay": {"priority": [[0.5, 1.0]]}})
    assert (report.source, report.role, report.incarnation, report.resumed) == ("default", "unknown", None, False)
    assert report.teachers["3"].steps == 2.0 and isinstance(report.teachers["3"].steps, float)
    assert report.replay.priority.shape == (2,)
    plain = report.to_dict()
    assert plain.keys() == {"schema", "source", "role", "resumed", "replay", "teachers"}, "None fields are omitted"
    assert CurriculumReport(lam=0.5).to_dict() == {"lambda": 0.5}


def test_typed_reports_feed_the_metrics_like_their_mappings():
    typed = Report(source="w0", role="rollout", incarnation="a", rollout=RolloutReport(env_steps=480, episodes=16),
                   curriculum=CurriculumReport(lam=0.5), icm=FitReport(scores=10))
    by_object, by_mapping = ServiceMetrics(), ServiceMetrics()
    by_object.apply(typed)
    by_mapping.apply(typed.to_dict())
    for m in (by_object, by_mapping):
        assert m.value("cmcl_env_steps_total") == 480 and m.value("cmcl_curriculum_lambda") == 0.5
        assert m.value("cmcl_curiosity_scores_total") == 10


def test_a_typed_report_is_validated_too():
    m = ServiceMetrics()
    with pytest.raises(ReportError, match=r"report key icm\.loss must be finite, got nan") as info:
        m.apply(Report(icm=FitReport(loss=float("nan"))))
    assert info.value.reason == "bad_value"
    assert m.value("cmcl_metrics_reports_rejected_total", {"reason": "bad_value"}) == 1
    with pytest.raises(ReportError, match="schema must be 1"):
        m.apply(Report(schema=2))


@pytest.mark.parametrize("report, reason, words", [
    ({"teachers": {"1": {"loss": float("inf")}}}, "bad_value", "teachers.1.loss must be finite"),
    ({"teachers": {"0": {"stepz": 1}}}, "unknown_key", "unknown report key teachers.0.stepz"),
    ({"teachers": {"0": 5}}, "bad_type", "teachers.0 must be a mapping, got int"),
    ({"learner": {"losses": {"a0": {"critic": "x"}}}}, "bad_type", "learner.losses.a0.critic must be a number"),
    ({"learner": {"losses": {"a0": {"a b": 1.0}}}}, "bad_value", "learner.losses.a0.a b is not a valid label"),
    ({"learner": {"weight_version": -1}}, "bad_value", "learner.weight_version must be in [0, inf], got -1"),
    ({"rollout": {"finished": {"win": {"predator": [2]}}}}, "bad_value",
     "rollout.finished.win.predator must hold finite values in [0, 1], got 1 bad of 1, e.g. [2.0]"),
    ({"rollout": {"finished": {"reward": {"a": [np.nan]}}}}, "bad_value", "rollout.finished.reward.a must hold"),
    ({"rollout": {"finished": {"lost": []}}}, "unknown_key", "unknown report key rollout.finished.lost"),
    ({"replay": {"rejected": {"bad_shape": -2}}}, "bad_value", "replay.rejected.bad_shape must be in [0, inf], got -2"),
    ({"replay": {"rejected": None}}, "bad_type", "replay.rejected must be a mapping, got NoneType"),
    ({"replay": {"agent_sampling_ess": {"0": 1.5}}}, "bad_value", "replay.agent_sampling_ess.0 must be in [0, 1]"),
    ({"replay": {"reward_rows_sampled": {"0": -0.1}}}, "bad_value", "replay.reward_rows_sampled.0 must be in"),
    ({"curriculum": {"lam": 0.5}}, "unknown_key", "unknown report key curriculum.lam"),
    ({"source": "a b"}, "bad_value", "source is not a valid label"),
    ({"incarnation": 1.5}, "bad_type", "incarnation must be a string label, got 1.5"),
    ({"weight_version": True}, "bad_type", "weight_version must be a number, got True"),
])
def test_bad_reports_name_the_path_and_the_value(report, reason, words):
    with pytest.raises(ReportError) as info:
        parse_report(report)
    assert info.value.reason == reason
    assert words in str(info.value)


def test_sample_keys_are_the_histograms_in_draw_order():
    assert tuple(HISTOGRAMS) == SAMPLE_KEYS

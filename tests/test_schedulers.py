"""One runner, two schedulers: every registered rule (cmcl.replay.registry.REGISTRY), its permuted control where the
rule's sampling has priorities to permute, and ACL's td_self variant, trained on one seed by the in-process scheduler
(services.runtime.calls.InProcessCalls) and by the Ray service (RayCalls), recorded from the run's own messages
(tests/recording_calls.py).

In process the run is one deterministic sequence: two runs sample and score exactly the same (slot, generation)
pairs in the same order. Across the schedulers the timing differs, so the structure is compared: the same score
columns written (those the rule needs: the teachers' difficulty, the ICM's curiosity, the online critics' |δ|),
every sampled row scored by the online critics before it was sampled where the rule's difficulty is theirs, and the
same keys in the summary and in the progress rows.
"""

from __future__ import annotations

import numpy as np
import pytest

from cmcl.config import config_from_dict
from cmcl.replay.messages import CURIOSITY, DIFFICULTY, ONLINE_TD
from cmcl.replay.registry import REGISTRY
from cmcl.replay.sampling import UniformSampling
from cmcl.system import layout_of
from tests.recording_calls import recorded_run
from tests.tiny import make_tiny_config

# (rule, priority.difficulty_transform, acl_variant): every rule; its permuted control where its sampling holds
# priorities; ACL's td_self (the online critics' scorer)
CASES = [(rule, "none", "teachers") for rule in REGISTRY]
CASES += [(rule, "permuted", "teachers") for rule, spec in REGISTRY.items() if spec.sampler is not UniformSampling]
CASES += [("acl", "none", "td_self")]
# on the Ray service in the default run (one per kind of scorer and the learner-side pick); the rest are extended
ON_RAY_BY_DEFAULT = {("maddpg", "none", "teachers"), ("cmcl", "none", "teachers"), ("acl", "none", "td_self"),
                     ("laber", "permuted", "teachers")}
NOT_BOTH_RUNNERS = {"metrics_port"}  # the service's own metrics endpoint


def case_id(case: tuple[str, str, str]) -> str:
    rule, transform, variant = case
    return "-".join([rule, *[part for part, plain in ((transform, "none"), (variant, "teachers")) if part != plain]])


def case_config(case: tuple[str, str, str]):
    """The tiny service config of one case, 16 episodes on seed 0."""
    rule, transform, variant = case
    data = make_tiny_config(rule, service=True, episodes=16, seed=0).to_dict()
    for team in data["teams"].values():
        team["priority"]["difficulty_transform"] = transform
        team["acl_variant"] = variant
    return config_from_dict(data)


def expected_columns(config) -> set[str]:
    """The score columns the rule's scorers write (its needs, as the layout of the config has them)."""
    layout = layout_of(config)
    scorers = ((DIFFICULTY, layout.teacher_agents.size), (CURIOSITY, layout.icm_agents.size),
               (ONLINE_TD, ONLINE_TD in layout.difficulty_source))
    return {column for column, present in scorers if present}


def progress_keys(directory) -> set[str]:
    from cmcl.run.rundir import RunDirectory

    return {key for row in RunDirectory.open(directory).rows("progress") for key in row}


def check_run(config, summary, outcome) -> None:
    """What every run of a case must show, on either scheduler."""
    assert summary["updates"] > 0 and outcome.sampled(), "the run made no learner update"
    assert outcome.columns == expected_columns(config)
    if ONLINE_TD in outcome.columns:
        assert not outcome.sampled_before_scored(ONLINE_TD)


@pytest.mark.parametrize("case", CASES, ids=case_id)
def test_the_in_process_scheduler_repeats_a_run_exactly(case, tmp_path):
    config = case_config(case)
    (summary, first), (_, second) = (recorded_run(config, tmp_path / name, in_process=True) for name in "ab")
    check_run(config, summary, first)
    assert len(first.events) == len(second.events)
    for ours, theirs in zip(first.events, second.events, strict=True):
        assert ours[0] == theirs[0] and all(np.array_equal(a, b) for a, b in zip(ours[1:], theirs[1:], strict=True))


@pytest.mark.parametrize("case", [pytest.param(c, id=case_id(c), marks=() if c in ON_RAY_BY_DEFAULT
                                               else pytest.mark.extended) for c in CASES])
def test_both_schedulers_score_sample_and_report_alike(case, tmp_path, ray_cluster):
    config = case_config(case)
    inline, inline_outcome = recorded_run(config, tmp_path / "inline", in_process=True)
    service, service_outcome = recorded_run(config, tmp_path / "service", in_process=False)
    check_run(config, inline, inline_outcome)
    check_run(config, service, service_outcome)
    assert inline_outcome.columns == service_outcome.columns
    assert set(inline) - NOT_BOTH_RUNNERS == set(service) - NOT_BOTH_RUNNERS
    assert progress_keys(tmp_path / "inline") == progress_keys(tmp_path / "service")

"""The pieces of bench/service_breakdown.py's breakdown: which role a process is, CPU over a window, the
learner's time split; and the instrumentation it reads: the pacing's reason for holding the learner back, the
supervisor's HeldClock, the learner's busy seconds in its report and on the metrics endpoint."""

import sys
from pathlib import Path

import numpy as np
import pytest

from bench.breakdown_sampling import core_shares, cpu_between
from cmcl.replay.messages import ReplayStatus
from cmcl.replay.pacing import Pacing
from cmcl.replay.ratelimit import RateLimiter
from services.observability.metrics import ServiceMetrics
from services.observability.report_schema import LearnerReport, Report
from services.runtime.call_budget import HeldClock

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from service_breakdown import group_of, learner_split, role_of_process  # noqa: E402


def test_processes_are_named_by_their_role():
    actors = {101: "learner", 102: "rollout worker 0"}
    assert role_of_process("ray::RolloutWorker.rollout", actors, 102) == "rollout worker 0"
    assert role_of_process("ray::Learner.update", {}, 7) == "learner (pid not asked)"
    assert role_of_process("ray::ICMWorker", {}, 7) == "ICM (pid not asked)"
    assert role_of_process("/venv/lib/python3.11/site-packages/ray/core/src/ray/raylet/raylet --node=x", {}, 7) == \
        "raylet"
    assert role_of_process("/venv/.../ray/core/src/ray/gcs/gcs_server --gcs_server_port=1", {}, 7) == "gcs_server"
    assert role_of_process("python /venv/.../ray/dashboard/dashboard.py --host=127.0.0.1", {}, 7) == "dashboard"
    assert role_of_process("ray::DashboardAgent", {}, 7) == "dashboard agent"
    assert role_of_process("ray::RuntimeEnvAgent", {}, 7) == "runtime env agent"
    assert role_of_process("python -u /venv/.../ray/_private/log_monitor.py --x", {}, 7) == "log monitor"
    assert role_of_process("ray::IDLE", {}, 7) == "idle Ray workers"
    assert role_of_process("/venv/bin/python -m services.runtime.reaper 42", {}, 7) == "reaper"
    assert role_of_process("ray::SomethingElse", {}, 7) == "other Ray worker"
    assert role_of_process("/usr/bin/sleep 3", {}, 7) == "other: sleep"
    assert [group_of(r) for r in ("teachers (folds 0,1)", "ICM", "rollout worker 1", "raylet", "driver (supervisor)")] \
        == ["scoring (teachers + ICM)", "scoring (teachers + ICM)", "rollout workers", "Ray's own processes",
            "driver (supervisor)"]


def test_cpu_over_a_window_and_its_share_of_the_cores():
    samples = [(0.0, 1.0), (1.0, 1.5), (2.0, 2.5), (3.0, 4.0)]
    assert cpu_between(samples, 1.0, 3.0) == 2.5
    assert cpu_between(samples, 1.5, 2.9) == 1.0  # the samples at or before each end
    assert cpu_between([(2.0, 0.3), (3.0, 0.8)], 1.0, 3.0) == 0.8  # started in the window: counted from 0
    assert cpu_between(samples, -2.0, -1.0) == 0.0
    assert core_shares(30.0, 20.0, 2) == (1.5, 0.75)
    with pytest.raises(ValueError):
        core_shares(1.0, 0.0, 2)


def test_the_learners_split_adds_up_to_the_window():
    split = learner_split(100.0, 60.0, 45.0, {"env_steps": 20.0, "scores": 5.0, "checkpoint": 2.0, "warmup": 0.0,
                                             "other": 0.0})
    assert split["computing_off_cpu_s"] == 15.0 and split["idle_s"] == 40.0
    assert split["waiting_with_call_s"] == pytest.approx(13.0) and split["held_env_steps_share"] == 0.2
    parts = ("computing", "held_env_steps", "held_scores", "held_checkpoint", "held_warmup", "held_other",
             "waiting_with_call")
    assert sum(split[p + "_share"] for p in parts) == pytest.approx(1.0)
    over = learner_split(10.0, 8.0, 8.0, {"env_steps": 4.0})  # the clocks read apart: held scaled to the idle time
    assert over["held_env_steps_s"] == pytest.approx(2.0) and over["waiting_with_call_s"] == 0.0


def test_the_pacing_says_what_holds_the_learner_back():
    def pacing(inserts: int, updates: int, scorer_steps: int) -> Pacing:
        learner, scorer = RateLimiter(0.5, warmup=4, slack=1.0), RateLimiter(1.0, slack=1.0)
        learner.record_insert(inserts)
        learner.record_sample(updates)
        scorer.record_insert(updates)
        scorer.record_sample(scorer_steps)
        return Pacing(learner, [], scorer)

    folds = np.zeros(0, np.int64)
    assert pacing(2, 0, 0).status(folds).updates_held_by == "warmup"
    assert pacing(8, 5, 5).status(folds).updates_held_by == "env_steps"  # 5 updates for 8 env steps at 1/2: ahead
    assert pacing(20, 5, 3).status(folds).updates_held_by == "scores"  # 2 fit steps behind, slack 1
    assert pacing(20, 5, 5).status(folds).updates_held_by == ""


def status(held_by: str) -> ReplayStatus:
    return ReplayStatus(allowed_updates=0 if held_by else 4, allowed_inserts=0, update_deficit=0.0,
                        scoring_deficit=0.0, teacher_allowed=(), icm_allowed=0, updates_held_by=held_by, size=0,
                        env_steps=0, episodes=0, updates=0, lam=0.1, incarnation="i")


def test_the_held_clock_counts_the_seconds_without_a_learner_call_by_reason():
    clock = HeldClock()
    clock.tick(0.0, 0, status("warmup"))
    clock.tick(2.0, 1, status(""))  # warm-up 2 s, then a call in flight
    clock.tick(5.0, 0, status("env_steps"))  # 3 s with a call: not counted
    clock.tick(6.5, 0, status("scores"))
    clock.tick(7.0, 0, status("env_steps"), during="checkpoint")
    clock.tick(9.0, 0, status(""))  # no call though updates are allowed: other
    clock.tick(9.25, 1, status(""))
    assert clock.seconds == {"warmup": 2.0, "env_steps": 1.5, "scores": 0.5, "checkpoint": 2.0, "other": 0.25}


def test_the_learners_busy_seconds_reach_the_metrics_endpoint():
    report = Report(source="learner", role="learner", incarnation="a",
                    learner=LearnerReport(updates=16, busy_s=1.5, busy_cpu_s=1.25))
    metrics = ServiceMetrics()
    metrics.apply(report)
    metrics.apply(Report(source="learner", role="learner", incarnation="a",
                         learner=LearnerReport(updates=32, busy_s=2.5, busy_cpu_s=2.0)))
    assert metrics.value("cmcl_learner_busy_seconds_total") == 2.5
    assert metrics.value("cmcl_learner_busy_cpu_seconds_total") == 2.0

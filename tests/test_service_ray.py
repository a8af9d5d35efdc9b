"""The service on a real embedded Ray (2 CPUs, one session-scoped cluster): every preset end to end, the
Prometheus endpoint, resume from a checkpoint, and a killed rollout worker being replaced."""

import re
import threading
import urllib.request

import pytest
from prometheus_client.parser import text_string_to_metric_families

from cmcl.run.rundir import RunDirectory
from services.launch import run_service
from services.observability.metrics import ServiceMetrics
from services.runtime.placement import InfeasibleResources, create_roles
from services.runtime.supervisor import Supervisor
from tests.tiny import make_tiny_config

pytestmark = pytest.mark.ray

REQUIRED = ["cmcl_replay_size", "cmcl_replay_inserts_total", "cmcl_replay_samples_total", "cmcl_replay_rejected_total",
            "cmcl_curriculum_lambda", "cmcl_difficulty", "cmcl_priority", "cmcl_teacher_scores_total",
            "cmcl_teacher_score_age_updates", "cmcl_curiosity_scores_total", "cmcl_icm_loss",
            "cmcl_learner_updates_total", "cmcl_learner_loss", "cmcl_env_steps_total", "cmcl_episodes_total",
            "cmcl_coverage_rate", "cmcl_episode_reward", "cmcl_actor_restarts_total", "cmcl_kp_branch_fraction",
            "cmcl_fold_score_coverage", "cmcl_sampling_ess_fraction", "cmcl_sample_age_updates"]


def samples(text):
    """{(name, frozenset(labels)): value} of an exposition text."""
    out = {}
    for family in text_string_to_metric_families(text):
        for s in family.samples:
            out[(s.name, frozenset(s.labels.items()))] = s.value
    return out


def value(parsed, name, **labels):
    return sum(v for (n, ls), v in parsed.items() if n == name and set(labels.items()) <= set(ls))


# per, acl and cmcl are extended (out of the default run's budget): maddpg stays, and the default run trains CMCL
# on the service end to end in tests/test_user_path.py (make run) and tests/test_own_env_service.py
@pytest.mark.parametrize("algorithm", ["maddpg", pytest.param("per", marks=pytest.mark.extended),
                                       pytest.param("acl", marks=pytest.mark.extended),
                                       pytest.param("cmcl", marks=pytest.mark.extended)])
def test_each_preset_runs_end_to_end(algorithm, tmp_path, ray_cluster):
    # cmcl runs the automatic choice (one stacked actor on 2 CPUs); acl runs K = 3 actors
    actors = {"service": {"teacher_actors": 3}} if algorithm == "acl" else {}
    config = make_tiny_config(algorithm, service=True, sections=actors, dir=str(tmp_path / algorithm))
    scraped = {}

    def progress(line):
        scraped["line"] = line
        match = re.search(r"http://127\.0\.0\.1:(\d+)/metrics", line)
        if match:
            scraped["port"] = match.group(1)
        elif "port" in scraped:  # scrape the live endpoint at every progress line; keep the latest
            url = f"http://127.0.0.1:{scraped['port']}/metrics"
            scraped["text"] = urllib.request.urlopen(url, timeout=10).read().decode()

    summary = run_service(config, RunDirectory.create(config.run.dir, config), progress=progress)
    brief = {k: v for k, v in summary.items() if k != "metrics_text"}
    assert summary["episodes"] >= 12 and summary["updates"] > 0, brief
    assert summary["update_deficit"] < 1, f"the learner caught up with one update per env step: {brief}"
    parsed = samples(summary["metrics_text"])
    for name in REQUIRED:
        assert re.search(rf"^# TYPE {name}", summary["metrics_text"], re.M), name
    assert value(parsed, "cmcl_replay_size") == min(600, summary["env_steps"])
    assert value(parsed, "cmcl_learner_updates_total") == summary["updates"]
    assert value(parsed, "cmcl_env_steps_total") == summary["env_steps"]
    assert 0.1 < value(parsed, "cmcl_curriculum_lambda") <= 1.0
    assert 0.0 <= value(parsed, "cmcl_coverage_rate") <= 1.0
    teacher_scores = value(parsed, "cmcl_teacher_scores_total")
    assert (teacher_scores > 0) == (algorithm in ("acl", "cmcl"))
    assert (value(parsed, "cmcl_curiosity_scores_total") > 0) == (algorithm == "cmcl")
    assert value(parsed, "cmcl_sample_age_updates_count") > 0, "the ages of sampled rows are reported"
    if algorithm in ("acl", "cmcl"):  # the curriculum's own gauges
        shares = [value(parsed, "cmcl_kp_branch_fraction", branch=b) for b in ("rising", "falling", "excluded")]
        assert abs(sum(shares) - 1) < 1e-6, shares
        folds = [value(parsed, "cmcl_fold_score_coverage", fold=str(f)) for f in range(config.teachers.num_folds)]
        assert all(0 <= f <= 1 for f in folds) and max(folds) > 0, folds
        assert 0 < value(parsed, "cmcl_sampling_ess_fraction") <= 1
    live = samples(scraped["text"])  # the last scrape of the live endpoint, at the final progress line
    assert value(live, "cmcl_learner_updates_total") == summary["updates"], "the live endpoint served the run"
    rows = list(RunDirectory.open(config.run.dir).rows("episode"))
    assert len(rows) == summary["episodes"]
    # the rows end with the final cut's progress row, its sampling entry in the inline rows' shape
    last = list(RunDirectory.open(config.run.dir).rows("progress"))[-1]
    assert last["episodes"] == summary["episodes"] and last["updates"] == summary["updates"]
    mode = {"maddpg": "uniform"}.get(algorithm, algorithm)
    assert last["sampling"]["modes"] == [mode] * config.env.spread.num_agents
    assert all(len(last["sampling"][k]) == config.env.spread.num_agents
               for k in ("ess_fraction", "reward_rows_sampled", "reward_rows_buffer"))
    if algorithm == "maddpg":  # uniform: ESS 1 and the sampled share is the buffer's
        assert last["sampling"]["ess_fraction"] == [1.0] * config.env.spread.num_agents
        assert last["sampling"]["reward_rows_sampled"] == pytest.approx(last["sampling"]["reward_rows_buffer"])
    assert ("kp_branches" in last) == (algorithm in ("acl", "cmcl"))
    # the final line shows the age of the teachers' scores (from the final replay report) where there are teachers
    assert ("score age" in scraped["line"]) == (algorithm in ("acl", "cmcl")), scraped["line"]


def test_resume_continues_counters(tmp_path, ray_cluster):
    # The learner may run up to service.slack_updates ahead of its ratio (1 update per 16 env steps after the
    # warm-up). At the default 256 the first run's 240 env steps (9 updates owed) can end 256 updates ahead, more
    # than the 15 that the resumed run's 240 steps add: whether the resumed run then updates at all would depend on
    # timing. At a slack of 8 it ends at most 8 ahead, so the resume owes at least 15 - 8 - 1 = 6 updates.
    config = make_tiny_config("acl", service=True, sections={"service": {"slack_updates": 8}},
                              dir=str(tmp_path / "resume"), episodes=8)
    run_dir = RunDirectory.create(config.run.dir, config)
    first = run_service(config, run_dir, progress=None)
    resumed_config = run_dir.config(("run.episodes=16",))
    second = run_service(resumed_config, run_dir, resume=True, progress=None)
    assert second["env_steps"] == first["env_steps"] + 8 * 30, "env steps continue from the snapshot"
    assert first["updates"] <= 9 + 8 + 1, "the learner ran further ahead than its slack"
    assert second["updates"] >= first["updates"] + 6, "the resumed run does the updates its env steps owe"
    episodes = [r["episodes"] for r in run_dir.rows("episode")]
    assert episodes == list(range(1, second["episodes"] + 1))
    # the training clock goes on from the checkpoint, as the inline runner's; segment_s is this command's
    clock = [r["elapsed_s"] for r in run_dir.rows("episode")]
    assert clock == sorted(clock), clock
    assert second["elapsed_s"] >= clock[first["episodes"] - 1] + second["segment_s"], (first, second)
    # so do its tallies: the warm-up held the learner in the first segment only; every segment checkpoints
    held = first["learner_held_s"]["warmup"]
    assert held > 0 and second["learner_held_s"]["warmup"] >= held, (first["learner_held_s"], second["learner_held_s"])
    assert second["checkpoint_seconds"][:len(first["checkpoint_seconds"])] == first["checkpoint_seconds"]
    assert len(second["checkpoint_seconds"]) > len(first["checkpoint_seconds"])


# out of the default run (its 10-minute budget): tests/test_service_faults.py kills a worker three times in the
# default run
@pytest.mark.extended
def test_a_killed_rollout_worker_is_replaced_and_training_goes_on(tmp_path, ray_cluster):
    """Rollout worker 0 is killed (ray.kill, restartable) in the middle of a rollout call: the supervisor sees that
    call fail, Ray restarts the worker (a new incarnation) and training goes on to the episode target.

    A kill from outside lands at no particular moment: the worker may have no call in flight then (a rollout
    takes milliseconds) and the supervisor's next call may reach the restarted worker, so no call fails. Hence,
    once its first report is applied, the worker is armed (calls run in submission order): the first env step
    of its next rollout kills the worker from inside that call and waits for the kill, so that call fails.
    """
    ray = ray_cluster
    config = make_tiny_config("maddpg", service=True, dir=str(tmp_path / "kill"), episodes=24)
    run_dir = RunDirectory.create(config.run.dir, config)
    metrics = ServiceMetrics()
    roles = create_roles(config, run_dir)
    supervisor = Supervisor(config, run_dir, roles, metrics, progress=None)
    apply, armed = supervisor._apply, []

    def die(*_):  # the armed worker's env step: kill this worker, then wait for the kill to end the process
        ray.kill(ray.get_runtime_context().current_actor, no_restart=False)
        threading.Event().wait(60)  # the kill ends this wait; the bound only turns a lost kill into a failure
        raise RuntimeError("ray.kill did not end the rollout worker within 60 s")

    def arm(worker):  # runs on the worker; a restart runs its constructor, which builds a fresh env
        worker.env.step = die

    def apply_then_arm(kind, index, value, *number):  # arm the worker once its first chunk has been reported
        apply(kind, index, value, *number)
        if kind == "rollout_report" and not armed:
            armed.append((value.rollout.episodes, roles.rollout[0].__ray_call__.remote(arm)))

    supervisor._apply = apply_then_arm
    summary = supervisor.run()
    assert armed and armed[0][0] < 24 and summary["episodes"] == 24
    parsed = samples(metrics.text())
    assert value(parsed, "cmcl_actor_restarts_total", role="rollout") >= 1
    assert summary["failures"].get("rollout", 0) + summary["failures"].get("chunk", 0) >= 1
    for handle in (roles.replay, roles.learner, *roles.rollout):
        ray.kill(handle)


def test_infeasible_resources_are_refused_clearly(tmp_path, ray_cluster):
    config = make_tiny_config("maddpg", service=True, sections={"service": {"rollout_workers": 9}},  # > 2 CPUs
                              dir=str(tmp_path / "big"))
    with pytest.raises(InfeasibleResources, match="rollout_workers"):
        create_roles(config, RunDirectory.create(config.run.dir, config))


@pytest.mark.parametrize("signal", ["critic_loss", "normalised_td", "coverage"])
def test_the_service_ends_a_run_whose_learning_stopped_progressing(tmp_path, ray_cluster, signal):
    """run.stop_progress in the supervisor, fed the learner's critic losses and normalised TD errors and the
    episodes' coverage: with an enormous threshold the run ends after a few 4-episode windows of the signal
    run.progress_signal names, far before its 400-episode budget."""
    config = make_tiny_config("maddpg", service=True, dir=str(tmp_path / "plateau"), episodes=400,
                              stop_progress=1e9, progress_window=4, progress_patience=2, progress_signal=signal)
    summary = run_service(config, RunDirectory.create(config.run.dir, config), progress=None)
    assert summary["plateau"] and summary["episodes"] < 200, {k: summary[k] for k in ("episodes", "updates")}

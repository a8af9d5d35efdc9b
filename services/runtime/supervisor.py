"""Supervisor: the pacing loop, keeping a bounded number of calls in flight to every role's Ray actor.

Where it sits: the only process that talks to every actor. It never pulls transition data: chunks, batches,
work and scores travel between actors as object refs owned by this process (so they survive the death of the
actor that produced them); it `ray.get`s only small typed statuses and metrics reports. Data flows one way:
rollout -> replay -> learner, and the scorers (`Roles.scorers`: the teacher groups, the ICM, the online critics
the learner hosts) each in one chain, `ReplayServer.work` -> the role's `score` -> `ReplayServer.write`; weights go
out once per version. Pacing comes from the replay server's `cmcl.replay.pacing.Pacing`, reported in every reply
(`ReplayStatus`) and turned into calls by `services.runtime.call_budget`. What a failed or hung call does (counts,
restarts, the end of the run) is services.runtime.failures. The actors themselves are started by
services.runtime.placement.create_roles.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections import Counter, deque
from collections.abc import Callable
from typing import Any

import numpy as np

from cmcl.config import Config
from cmcl.envs.factory import EnvFactoryError
from cmcl.io.atomic import atomic_write_bytes
from cmcl.progress.clock import RunClock
from cmcl.progress.learning import LearningProgress, agent_mean
from cmcl.progress.rows import TrainingDiverged, episode_rows, solved, window_summary
from cmcl.replay.messages import ReplayStatus
from cmcl.replay.registry import early_notes, sampling_name, uses_lambda
from cmcl.run.rundir import RunDirectory
from cmcl.system import layout_of
from services.observability.metrics import ServiceMetrics
from services.observability.progress_view import ProgressView
from services.observability.report_schema import Report
from services.observability.run_tallies import add_tallies, tallies
from services.runtime.call_budget import HeldClock, calls_to_issue
from services.runtime.calls import InProcessCalls, RayCalls
from services.runtime.failures import Failures, end_if_write_failure
from services.runtime.health import actor_key
from services.runtime.placement import Roles, ScorerRole

# Outputs of one actor that go to the replay server. They are forwarded only once ready: an actor runs one
# caller's calls in submission order, so a replay call still waiting for its argument would hold up every
# call queued behind it (samples, work for teachers) and serialise the whole pipeline.
FORWARD = {"chunk": ("insert", "rollout"), "feedback": ("learner_result", "learner"),
           "teacher_scores": ("write", "teacher"), "icm_scores": ("write", "icm"), "online_scores": ("write", "online")}
REPORT_EVERY_S = 2.0


class Supervisor:
    """The pacing loop. `run()` trains until run.episodes episodes are stored (or run.max_seconds)."""

    def __init__(self, config: Config, run_dir: RunDirectory, roles: Roles, metrics: ServiceMetrics,
                 progress: Callable[[str], None] | None = print, stop: Callable[[], bool] | None = None,
                 calls: RayCalls | InProcessCalls | None = None):
        """`stop`: polled between rounds of work; once it returns True the run ends as at its budget (drain, final
        cut, every role checkpointed) and the summary says `stopped` (a graceful SIGINT / SIGTERM). `calls`: the
        scheduler (services.runtime.calls): Ray actor calls (the default) or the same roles called in this process."""
        self.config, self.run_dir, self.roles, self.metrics, self.progress = config, run_dir, roles, metrics, progress
        self.calls = calls if calls is not None else RayCalls()
        self.stop = stop
        self.stopped = False  # the run ended because `stop` said so
        self.env_error: EnvFactoryError | None = None  # the user's environment raised: the run ends, kept
        self.checkpoint_seconds: list[float] = []  # wall seconds of each checkpoint (drain + every role's save)
        self.paths = run_dir.service_paths()
        self.pending: dict[Any, tuple[str, int, int]] = {}  # ref -> (kind, actor index, submission number)
        self.submitted = 0  # calls tracked so far (numbers them in submission order)
        self.inflight: Counter[tuple[str, int]] = Counter()  # calls in flight per (role, actor index)
        self.status: ReplayStatus = self._ask_replay("status")
        self.status_number = 0  # submission number of the replay call that returned `status`
        # a call to the replay server failed with it: it may have stored (logged) what it never acknowledged, so
        # its status is asked afresh before more work is handed out (`_issue`)
        self.replay_failed = False
        self.weights = self.calls.submit(roles.learner, "publish")
        self.version = -1
        self.window: deque[dict[str, Any]] = deque(maxlen=config.run.smoothing_window)
        self.failures = Failures(config, roles)  # failed and hung calls, restarts, recovery times
        self.held = HeldClock()  # seconds the learner had no call, by what held it back (the replay's pacing)
        self.lags: dict[str, int] = {}  # weight versions each rollout worker / teacher is behind
        self.episodes_logged = 0
        self.solved = False  # the coverage target run.stop_coverage was reached
        # run.stop_progress: fed the learner's critic losses and the episodes' coverage (a resumed service run
        # starts it afresh)
        self.learning_progress = LearningProgress.from_run_config(config.run)
        self.last_replay_report: Report | None = None
        self.last_losses: dict[str, list[float]] = {}  # the learner's last reported losses, per kind and agent
        self.intrinsic_reward: float | None = None  # the learner's last mean coef·ρ (icm.intrinsic_reward_coef > 0)
        self.clock = RunClock()  # the run's training clock (a resumed run's goes on: restore_counters)
        algorithms = layout_of(config).algorithms
        self.view = ProgressView(config.run.episodes, self.clock, self.status,
                                 [sampling_name(a) for a in algorithms], config.run.max_seconds,
                                 early_notes(algorithms), uses_lambda(algorithms))
        self._first_reports()

    def _first_reports(self) -> None:
        """Apply one report from every role that has a `report` call before any work, so each actor's
        incarnation is known from the start: a role that dies before its first periodic report (a replay server
        killed in its first insert) is still counted as a restart when its new incarnation reports."""
        r = self.roles
        handles = [("replay_report", r.replay), ("learner_report", r.learner),
                   *((f"{s.kind}_report", s.handle) for s in r.scorers if s.kind != "online")]
        refs = [self.calls.submit(h, "report") for _, h in handles]
        for (kind, _), report in zip(handles, map(self.calls.get, refs), strict=True):
            self.metrics.apply(report)
            if kind == "replay_report":
                self.last_replay_report = report

    # ------------------------------------------------------------------ issuing work
    def _track(self, ref: Any, kind: str, index: int = 0) -> None:
        """Remember a call just submitted, numbered in submission order."""
        self.submitted += 1
        self.pending[ref] = (kind, index, self.submitted)
        self.failures.watch.submitted(ref)

    def _issue(self, rollouts: bool = True) -> None:
        """Hand out every piece of work the replay server's allowances leave room for (`services.runtime.call_budget`).
        After a replay server's failure its status is asked first: an insert whose reply died with the server may be
        in its log, and a stale count would collect a chunk more than run.episodes."""
        if self.replay_failed:
            self.status, self.status_number = self._ask_replay("status"), self.submitted
            self.replay_failed = False
        r, svc, submit = self.roles, self.config.service, self.calls.submit
        calls = calls_to_issue(self.status, self.inflight, self.config, len(r.rollout),
                               r.teacher_groups, r.icm is not None, rollouts, r.online_critics)
        for w, worker in enumerate(r.rollout):
            for _ in range(calls[("rollout", w)]):
                chunk_ref, report = submit(worker, "rollout", self.weights, returns=2)
                self._track(report, "rollout_report", w)
                self._track(chunk_ref, "chunk", w)
                self.inflight[("rollout", w)] += 1
        for _ in range(calls[("learner", 0)]):
            batch, _ = submit(r.replay, "sample", svc.updates_per_call, returns=2)
            feedback, report = submit(r.learner, "update", batch, returns=2)
            self._track(report, "learner_report")
            self._track(feedback, "feedback")
            self.inflight[("learner", 0)] += 1
        for role in r.scorers:
            for _ in range(calls[(role.kind, role.index)]):
                self._score(role)

    def _score(self, role: ScorerRole) -> None:
        """One scorer's chain: the replay server's `work` for it -> its `score` -> (forwarded once ready) `write`."""
        r, submit = self.roles, self.calls.submit
        work, _ = submit(r.replay, "work", role.scorer, self.config.service.fit_steps_per_call, returns=2)
        scores, report = submit(role.handle, "score", work, *([self.weights] if role.weights else []), returns=2)
        self._track(report, "learner_report" if role.kind == "online" else f"{role.kind}_report", role.index)
        self._track(scores, f"{role.kind}_scores", role.index)
        self.inflight[(role.kind, role.index)] += 1

    # ------------------------------------------------------------------ replies
    def _collect(self, timeout: float) -> None:
        """Wait for at least one reply (up to `timeout` s) and apply every reply that is ready."""
        if not self.pending:
            return
        for ref in self.calls.wait(list(self.pending), timeout):
            kind, index, number = self.pending.pop(ref)
            self.failures.watch.done(ref)
            if kind in FORWARD:  # data for the replay server, now ready: hand over the ref, never the data
                self._track(self.calls.submit(self.roles.replay, FORWARD[kind][0], ref), FORWARD[kind][1], index)
                if kind == "chunk" and self.roles.online_critics:  # ACL td_self: the online critics score the rows
                    self._score(self.roles.online)  # at insertion, before they can be sampled (ALGORITHM.md A11)
                continue
            try:
                value = self.calls.get(ref)
            except self.calls.FAILED as err:  # a Ray actor's call failed (none in one process: a role's error
                # propagates from submit)
                if isinstance(getattr(err, "cause", None), EnvFactoryError):  # the user's env (an observation that
                    if self.env_error is None:  # does not fit its space, a crash): a retry meets it again; the run
                        raise err.cause from None  # is checkpointed, then the CLI says it in one line
                    continue  # another worker's, while the run is being kept: said once
                end_if_write_failure(err)  # a full disk
                self.replay_failed |= self.failures.call_failed(kind, index, err, self.inflight) == ("replay", True)
                continue
            self._apply(kind, index, value, number)

    def _apply(self, kind: str, index: int, value: Any, number: int = 0) -> None:
        """Apply one reply; `number` is its call's submission number (see `_track`).

        Replies are applied in any order (`ray.wait` hands out ready refs in no particular order), but the replay
        server runs this process's calls in submission order, so the status of the call submitted last is the
        newest: an older one never replaces it (a stale episode count would let `_issue` collect more episodes
        than run.episodes).
        """
        self.failures.recovery.replied(actor_key(kind, index))
        if isinstance(value, ReplayStatus):  # the replay server's reply that ends a chain of `kind`'s work
            if number > self.status_number:
                self.status, self.status_number = value, number
            if value.error:
                self.failures.replay_error(value.error)
            self.inflight[(kind, index)] -= 1
            return
        self.metrics.apply(value)  # a Report, dispatched on the role that sent it
        if value.role == "replay":
            self.last_replay_report = value
            return
        if value.weight_version is not None:
            self.lags[value.source] = max(0, self.version - int(value.weight_version))
        if value.role == "learner" and value.learner.losses:
            losses = [loss for kinds in value.learner.losses.values() for loss in kinds.values()]
            if not np.isfinite(losses).all():  # the learner's weights diverged: the run ends (services/launch.py)
                raise TrainingDiverged(self.config, self.status.episodes, self.status.updates, "the learner's losses")
            self.last_losses = {kind: [agent[kind] for agent in value.learner.losses.values()]
                                for kind in ("critic", "actor")}  # per agent, in index order
            critic = [kinds["critic"] for kinds in value.learner.losses.values()]
            normalised = agent_mean(kinds.get("critic_normalised", np.nan) for kinds in value.learner.losses.values())
            self.learning_progress.record(self.status.episodes, sum(critic) / len(critic), normalised)
            if value.learner.intrinsic_reward is not None:
                self.intrinsic_reward = value.learner.intrinsic_reward
        if value.role == "learner" and value.learner.weight_version != self.version:
            self.version = value.learner.weight_version
            self.weights = self.calls.submit(self.roles.learner, "publish")
        if value.role == "rollout":
            self._log_episodes(value)

    def _log_episodes(self, report: Report) -> None:
        """Append one 'episode' row per finished episode of a rollout report to metrics.jsonl."""
        rows = episode_rows(report.rollout.finished.to_dict(), self.episodes_logged + 1,
                            elapsed_s=self.clock.elapsed(), worker=report.source,
                            weight_version=report.weight_version or 0)
        self.episodes_logged += len(rows)
        self.window.extend(rows)
        for row in rows:
            self.run_dir.log(row)
            self.learning_progress.record_episode(row["episodes"], row.get("coverage"))  # progress_signal coverage

    # ------------------------------------------------------------------ progress, checkpoints
    def progress_row(self) -> dict[str, Any]:
        """The progress row of metrics.jsonl (services.observability.progress_view) with the learner's last losses per
        agent ("critic_loss", "actor_loss": lists over agents in index order) once it has reported them, and with
        curiosity as a reward the last update's mean coef·ρ ("intrinsic_reward")."""
        row = self.view.row(self.status, self.last_replay_report)
        # the task curriculum's newest stage (cmcl.rollout.task_curriculum)
        if self.window and "task_stage" in self.window[-1]:
            row["task_stage"] = int(max(r["task_stage"] for r in self.window))
        if self.intrinsic_reward is not None:
            row["intrinsic_reward"] = self.intrinsic_reward
        return {**row, **{f"{kind}_loss": losses for kind, losses in self.last_losses.items()}}

    def progress_line(self) -> str:
        """One terminal line (services.observability.progress_view)."""
        return self.view.line(self.status, self.last_replay_report, self.lags, self.window)

    def drain(self) -> None:
        """Wait for every call in flight (a consistent cut for checkpoints and the end)."""
        while self.pending:
            self._collect(timeout=5.0)

    def _caught_up(self, fresh: bool = False) -> bool:
        """Whether no learner / teacher / ICM call is in flight and each has caught up with its ratio (< 1 step).

        `fresh=True` drains every call still in flight and asks the replay server for its status now.
        """
        if any(n for (role, _), n in self.inflight.items() if role in ("learner", "teacher", "icm", "online")):
            return False
        if fresh:
            self._settle()
        return self.status.update_deficit < 1 and self.status.scoring_deficit < 1

    def _ask_replay(self, method: str) -> Any:
        """The reply of one of the replay server's read-only methods ("status", "report"), waited for. The call is
        retried until the server answers: one that reaches a process that has just died, before Ray has noticed
        (ActorUnavailableError), runs again on the restarted server; a server out of restarts raises
        ActorDiedError."""
        return self.calls.get(self.calls.submit(self.roles.replay, method, retry=True))

    def _settle(self) -> None:
        """Drain every call in flight, then take the replay server's status now (newer than any reply)."""
        self.drain()
        self.status, self.status_number = self._ask_replay("status"), self.submitted

    def final_cut(self) -> None:
        """The end of a run as one consistent cut: settle (drain, fresh status), then one final replay report, so
        the metrics, the summary and the checkpoint all describe the same state."""
        self._settle()
        self._apply("replay_report", 0, self._ask_replay("report"))

    def checkpoint(self) -> None:
        """Drain, then have every role save its own state atomically; then the supervisor's counters. A role that
        dies while saving keeps its previous checkpoint (every save is atomic) and is counted as a failure."""
        started = time.perf_counter()
        self.drain()
        r = self.roles
        submit = self.calls.submit
        saves = {"learner": [submit(r.learner, "save")], "replay": [submit(r.replay, "snapshot")],
                 "rollout": [submit(w, "save") for w in r.rollout],  # the task curriculum's stage, if any
                 "teacher": [submit(t, "save") for t in r.teachers], "icm": [submit(r.icm, "save")] if r.icm else []}
        for role, refs in saves.items():
            for ref in refs:
                try:
                    self.calls.get(ref)
                except self.calls.FAILED as err:
                    end_if_write_failure(err)  # a full disk: the role's older checkpoint stays
                    self.failures.save_failed(role, err)
        self.checkpoint_seconds.append(time.perf_counter() - started)  # (its own counters' write below excluded)
        summary = {"runner": "inline" if isinstance(self.calls, InProcessCalls) else "service",
                   "episodes_logged": self.episodes_logged, "status": dataclasses.asdict(self.status),
                   "time": time.time(), "elapsed_s": self.clock.elapsed(), "tallies": self.tallies()}
        atomic_write_bytes(self.paths["supervisor"], json.dumps(summary).encode())

    def restore_counters(self) -> None:
        """On resume: continue the episode numbering of metrics.jsonl, the training clock (elapsed_s) and the tallies
        from the last checkpoint."""
        path = self.paths["supervisor"]
        if path.exists():
            saved = json.loads(path.read_text())
            self.episodes_logged = int(saved["episodes_logged"])
            self.clock.before_s = float(saved["elapsed_s"])
            add_tallies(saved["tallies"], self.failures, self.held, self.checkpoint_seconds)
            self.run_dir.truncate_rows_after(self.episodes_logged)

    def tallies(self) -> dict[str, Any]:
        """What the run has counted so far, over every segment (services.observability.run_tallies; the summary's
        keys)."""
        return tallies(self.failures, self.held, self.checkpoint_seconds)

    def run(self) -> dict[str, Any]:
        """Train until the episode target (or the time budget) is reached; checkpoint periodically and at the end."""
        cfg = self.config
        last_report = last_ckpt = time.perf_counter()
        report_ref = None
        try:
            while True:
                if self.stop is not None and self.stop():
                    self.stopped = True
                    break
                if cfg.run.max_seconds and self.clock.segment() > cfg.run.max_seconds:
                    break
                if solved(self.window, cfg.run):
                    self.solved = True
                    break
                if self.learning_progress.plateaued:  # run.stop_progress
                    break
                collecting = self.status.episodes < cfg.run.episodes
                if not collecting and self._caught_up() and self._caught_up(fresh=True):
                    break  # episode target reached; the learner, every teacher and the ICM have caught up
                self._issue(rollouts=collecting)
                self.held.tick(time.perf_counter(), self.inflight[("learner", 0)], self.status)
                self._collect(timeout=0.5)
                self.failures.kill_hung(self.pending)
                now = time.perf_counter()
                if now - last_report >= REPORT_EVERY_S and report_ref is None:
                    report_ref = self.calls.submit(self.roles.replay, "report")
                    self._track(report_ref, "replay_report")
                if report_ref is not None and report_ref not in self.pending:
                    report_ref, last_report = None, now
                    self.view.refresh(self.status)
                    self.metrics.update_rates()
                    if self.progress is not None:
                        self.progress(self.progress_line())
                    self.run_dir.log(self.progress_row())
                if now - last_ckpt >= cfg.service.checkpoint_every_s:
                    self.held.tick(now, self.inflight[("learner", 0)], self.status, during="checkpoint")
                    self.checkpoint()
                    last_ckpt = time.perf_counter()
        except EnvFactoryError as err:  # the user's environment raised: keep the run (final cut, checkpoint), then
            self.env_error = err  # the CLI says it in one line
        self.final_cut()
        self.checkpoint()
        if self.env_error is not None:
            raise self.env_error
        self.view.refresh(self.status)
        self.run_dir.log(self.progress_row())  # the rows end at the final cut
        if self.progress is not None:
            self.progress(self.progress_line())
        now = time.perf_counter()  # one instant: elapsed_s = the earlier segments' + segment_s
        return {**dataclasses.asdict(self.status), **self.status.counters(), **self.view.rates,
                **self.tallies(), "solved": self.solved, "plateau": self.learning_progress.plateaued,
                "stopped": self.stopped, "episodes_logged": self.episodes_logged,
                "window": window_summary(self.window), "elapsed_s": self.clock.elapsed(now),
                "segment_s": self.clock.segment(now)}

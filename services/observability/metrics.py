"""Prometheus metrics of the whole CMCL service: one registry, one HTTP endpoint, fed by actor reports.

Where it sits: `services/launch.py` (the supervisor, a single process) creates one `ServiceMetrics`, calls
`serve(port, host)` once, and passes every report an actor returns to `apply(report)`. Actors never touch
Prometheus: they send a `Report` (services/observability/report_schema.py, built by the roles of this code base and
not validated again here); `apply` plans its metric updates, then commits them. deploy/prometheus.yml scrapes the
endpoint; deploy/grafana/dashboards/cmcl.json shows it. The endpoint binds 127.0.0.1 unless told otherwise (the compose
file passes 0.0.0.0 inside its private network) and uses its own `CollectorRegistry`, never prometheus-client's global
one.

Counter rule (the totals N of the report). Actors send cumulative totals since their process started; the
supervisor keeps the last total per (source, metric, labels) and adds the difference, so a repeated report adds
nothing. When `incarnation` changes, one restart of `role` is counted and, unless `resumed` is true, the source's
remembered totals are dropped (the new totals are added whole, even when larger than the old). With `resumed`
true the totals continue the old series: only the part above the last total seen is added. A total lower than
the last one from the same incarnation is an older report applied late (the supervisor applies replies in the
order they become ready, which is not the order they were sent) and adds nothing; from a report without an
incarnation it means the actor restarted and counts from zero: the whole new total is added (Prometheus' rule).

Gauges are last-writer-wins (size, capacity, λ and coverage come from the one replay server). The rates
`cmcl_env_steps_per_second` / `cmcl_updates_per_second` are counter growth over the last `rate_window` seconds of
supervisor time (default 30), refreshed by `apply` at most every `rate_interval` seconds, or on demand by
`update_rates(now)`. The window spans several reports: the learner reports once per call of
`service.updates_per_call` updates, which on a loaded machine can take longer than `rate_interval`, and a rate over
the last refresh alone then read 0 while it trained (the dashboard's "Updates / s", at random).

Histogram rule (the replay samples of the report). Each report adds at most `max_samples` (default 512) values
per histogram, a uniform subsample drawn with the seeded generator when the array is larger (in SAMPLE_KEYS
order), so a report weighs the same whatever the buffer size and costs a bounded amount; bucket counts are added
in one vectorised step. Histogram `_count` therefore counts observed samples, not transitions. Episode
statistics (rollout.finished) feed moving averages over the last `window` episodes (default 100, ALGORITHM.md
§6.3) exported as gauges.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from prometheus_client import CollectorRegistry, generate_latest, start_http_server

from cmcl.progress.rates import WindowedRate
from services.observability.metric_families import HISTOGRAMS, NumpyHistogram, define_metrics
from services.observability.report_schema import SAMPLE_KEYS, FinishedEpisodes, Report

__all__ = ["DEFAULT_MAX_SAMPLES", "HISTOGRAMS", "NumpyHistogram", "Report", "ServiceMetrics"]

DEFAULT_MAX_SAMPLES = 512

@dataclass
class _Plan:
    """The metric operations of one parsed report, applied together once planned."""

    counter: list[tuple[str, tuple, float]] = field(default_factory=list)  # (counter, labels, cumulative total)
    gauge_sets: list[tuple[str, tuple, float]] = field(default_factory=list)  # (gauge, labels, value)
    hist: list[tuple[str, np.ndarray]] = field(default_factory=list)  # (sample key, values [<= max_samples])
    episodes: list[tuple[str, str, np.ndarray]] = field(default_factory=list)  # (gauge, team or "", values)

    def count(self, metric: str, total: float | None, labels: tuple = ()) -> None:
        """Plan a cumulative-total counter update (None: absent from the report)."""
        if total is not None:
            self.counter.append((metric, labels, total))

    def gauge(self, gauge: str, value: float | None, labels: tuple = ()) -> None:
        """Plan a gauge set (None: absent from the report)."""
        if value is not None:
            self.gauge_sets.append((gauge, labels, value))


@dataclass
class _SourceState:
    """What the supervisor remembers about one report source: incarnation and last cumulative totals."""

    incarnation: str | None
    totals: dict[tuple, float] = field(default_factory=dict)


class ServiceMetrics:
    """Every metric of the service in one registry, updated from actor reports (see the module docstring)."""

    def __init__(self, *, max_samples: int = DEFAULT_MAX_SAMPLES, window: int = 100, seed: int = 0,
                 rate_interval: float = 5.0, rate_window: float = 30.0,
                 clock: Callable[[], float] = time.monotonic):
        for name, value in (("max_samples", max_samples), ("window", window)):
            if value < 1:
                raise ValueError(f"{name} must be >= 1, got {value!r}")
        self.registry = CollectorRegistry(auto_describe=True)
        if not rate_window >= rate_interval > 0:
            raise ValueError(f"need rate_window >= rate_interval > 0, got {rate_window!r} and {rate_interval!r}")
        self.max_samples, self.window, self.rate_interval, self._clock = max_samples, window, rate_interval, clock
        self._rng = np.random.default_rng(seed)
        self._lock = threading.Lock()
        self._sources: dict[str, _SourceState] = {}
        self._episode_windows: dict[tuple[str, str], np.ndarray] = {}
        self._published_version: int | None = None
        self._actor_versions: dict[str, int] = {}
        self._accumulated = {"env_steps": 0.0, "learner_updates": 0.0}
        self._rates = WindowedRate(rate_window)  # env steps and updates of each refresh
        self._server: Any = None
        self._thread: threading.Thread | None = None
        self.gauges, self.counters, self.histograms = define_metrics(self.registry)

    def metric_names(self) -> frozenset[str]:
        """Names as exposed: gauges as is, counters with `_total`, histograms without the bucket suffixes."""
        names = set()
        for family in self.registry.collect():
            names.add(family.name + "_total" if family.type == "counter" else family.name)
        return frozenset(names)

    def _subsample(self, values: Any) -> np.ndarray:
        """`values` (array-like, any shape) as float64 [n], or a uniform subsample [max_samples] of them without
        replacement when n is larger."""
        values = np.asarray(values, dtype=np.float64).ravel()
        if values.size > self.max_samples:
            return self._rng.choice(values, size=self.max_samples, replace=False)
        return values

    def _plan(self, report: Report) -> _Plan:
        """The operations of a report, section by section; draws the histogram subsamples."""
        plan = _Plan()
        if report.checkpoints_refused is not None:
            plan.count("checkpoints_refused", report.checkpoints_refused, (report.role,))
        if (replay := report.replay) is not None:
            plan.gauge("replay_size", replay.size)
            plan.gauge("replay_capacity", replay.capacity)
            plan.gauge("score_coverage", replay.score_coverage)
            plan.gauge("sampling_ess", replay.sampling_ess)
            for branch, share in (replay.kp_branches or {}).items():
                plan.gauge("kp_branch", share, (branch,))
            for fold, share in (replay.fold_score_coverage or {}).items():
                plan.gauge("fold_score_coverage", share, (fold,))
            for agent, ess in (replay.agent_sampling_ess or {}).items():
                plan.gauge("agent_sampling_ess", ess, (agent,))
            for where, shares in (("sampled", replay.reward_rows_sampled), ("buffer", replay.reward_rows_buffer)):
                for agent, share in (shares or {}).items():
                    plan.gauge("reward_rows", share, (agent, where))
            plan.count("replay_inserts", replay.inserts)
            plan.count("replay_samples", replay.samples)
            for reason, total in (replay.rejected or {}).items():
                plan.count("replay_rejected", total, (reason,))
            if replay.stale_scores is not None:
                plan.count("replay_stale_scores", replay.stale_scores)
            for key in SAMPLE_KEYS:
                if getattr(replay, key) is not None:
                    plan.hist.append((key, self._subsample(getattr(replay, key))))
        if report.curriculum is not None:
            plan.gauge("lambda", report.curriculum.lam)
        for tid, teacher in (report.teachers or {}).items():
            plan.count("teacher_steps", teacher.steps, (tid,))
            plan.count("teacher_scores", teacher.scores, (tid,))
            plan.gauge("teacher_loss", teacher.loss, (tid,))
        if (icm := report.icm) is not None:
            plan.count("icm_steps", icm.steps)
            plan.count("curiosity_scores", icm.scores)
            plan.gauge("icm_loss", icm.loss)
        if (learner := report.learner) is not None:
            plan.count("learner_updates", learner.updates)
            plan.count("learner_busy_seconds", learner.busy_s)
            plan.count("learner_busy_cpu_seconds", learner.busy_cpu_s)
            for agent, kinds in (learner.losses or {}).items():
                for kind, value in kinds.items():
                    plan.gauge("learner_loss", value, (agent, kind))
            plan.gauge("intrinsic_reward", learner.intrinsic_reward)
        if (rollout := report.rollout) is not None:
            plan.count("env_steps", rollout.env_steps)
            plan.count("episodes", rollout.episodes)
            self._plan_finished(plan, rollout.finished)
        return plan

    @staticmethod
    def _plan_finished(plan: _Plan, finished: FinishedEpisodes | None) -> None:
        """Per-episode values for the moving-average gauges: (gauge, team or "", values [episodes])."""
        if finished is None:
            return
        for key in ("coverage", "success"):
            if getattr(finished, key) is not None:
                plan.episodes.append((f"{key}_rate", "", np.asarray(getattr(finished, key), np.float64).ravel()))
        for teams, gauge in ((finished.reward, "episode_reward"), (finished.win, "win_rate")):
            plan.episodes.extend((gauge, str(team), np.asarray(values, np.float64).ravel())
                                 for team, values in (teams or {}).items())

    def apply(self, report: Report) -> None:
        """Apply one actor report atomically."""
        with self._lock:  # one report at a time (the subsampling generator is shared too)
            self._commit(report, self._plan(report))
            self.counters["reports"].inc()
            now = self._clock()
            if self._rates.last is None or now - self._rates.last >= self.rate_interval:
                self._update_rates(now)

    def _commit(self, report: Report, plan: _Plan) -> None:
        """Apply the plan of a report (caller holds the lock)."""
        source, incarnation, resumed = report.source, report.incarnation, report.resumed
        state = self._source_state(source, report.role, incarnation, resumed)
        for metric, labels, total in plan.counter:
            delta = self._delta(state, (metric, labels), total, resumed or incarnation is not None)
            if delta > 0:
                counter = self.counters[metric]
                (counter.labels(*labels) if labels else counter).inc(delta)
                if metric in self._accumulated:
                    self._accumulated[metric] += delta
        for gauge, labels, value in plan.gauge_sets:
            metric = self.gauges[gauge]
            (metric.labels(*labels) if labels else metric).set(value)
        for name, values in plan.hist:
            self.histograms[name].observe_many(values)
        for gauge, team, values in plan.episodes:
            self._extend_window(gauge, team, values)
        if report.weight_version is not None:
            self._actor_versions[source] = report.weight_version
        if report.learner is not None and report.learner.weight_version is not None:
            self._published_version = report.learner.weight_version
        self._update_lags()

    def _source_state(self, source: str, role: str, incarnation: str | None, resumed: bool) -> _SourceState:
        """The source's bookkeeping; a changed incarnation counts a restart and (unless resumed) resets totals."""
        state = self._sources.get(source)
        if state is None:
            state = self._sources[source] = _SourceState(incarnation)
        elif incarnation is not None and incarnation != state.incarnation:
            if state.incarnation is not None:
                self.counters["restarts"].labels(role).inc()
            state.incarnation = incarnation
            if not resumed:
                state.totals.clear()
        return state

    @staticmethod
    def _delta(state: _SourceState, key: tuple, total: float, continues: bool) -> float:
        """Counter increase for a new cumulative `total` (the rule of the module docstring).

        `continues`: the report continues the series counted so far (same incarnation, or resumed), so a lower
        total is no reset.
        """
        last = state.totals.get(key, 0.0)
        if total >= last:
            state.totals[key] = total
            return total - last
        if continues:  # an older report of this process, or restored totals below what we counted: nothing new
            return 0.0
        state.totals[key] = total  # reset: the actor counts from zero again
        return total

    def _extend_window(self, gauge: str, team: str, values: np.ndarray) -> None:
        """Append per-episode values to the moving window and set the gauge to the window mean."""
        if values.size == 0:
            return
        key = (gauge, team)
        window = np.concatenate([self._episode_windows.get(key, np.empty(0)), values])[-self.window:]
        self._episode_windows[key] = window
        metric = self.gauges[gauge]
        (metric.labels(team) if team else metric).set(float(window.mean()))

    def _update_lags(self) -> None:
        """Set the weight lag of every actor against the last published version."""
        for actor, version in self._actor_versions.items() if self._published_version is not None else ():
            self.gauges["weight_lag"].labels(actor).set(max(0, self._published_version - version))

    def update_rates(self, now: float | None = None) -> None:
        """Recompute env steps/s and updates/s from counter growth over the last `rate_window` seconds."""
        with self._lock:
            self._update_rates(self._clock() if now is None else now)

    def _update_rates(self, now: float) -> None:
        rates = self._rates.mark(now, (self._accumulated["env_steps"], self._accumulated["learner_updates"]))
        if rates is not None:
            self.gauges["env_steps_per_second"].set(rates[0])
            self.gauges["updates_per_second"].set(rates[1])

    def text(self) -> str:
        """The Prometheus exposition text of every metric (what /metrics serves)."""
        return generate_latest(self.registry).decode("utf-8")

    def value(self, name: str, labels: Mapping[str, str] | None = None) -> float | None:
        """One sample's current value (e.g. 'cmcl_replay_inserts_total'), None if absent."""
        return self.registry.get_sample_value(name, dict(labels or {}))

    def serve(self, port: int = 0, host: str = "127.0.0.1") -> int:
        """Start the /metrics HTTP endpoint on host:port (0 picks a free port); return the bound port."""
        if self._server is not None:
            raise RuntimeError(f"metrics endpoint already serving on {self.address}")
        if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
            raise ValueError(f"port must be an integer in [0, 65535], got {port!r}")
        self._server, self._thread = start_http_server(port, addr=host, registry=self.registry)
        return int(self._server.server_port)

    @property
    def address(self) -> tuple[str, int] | None:
        """(host, port) the endpoint is bound to, or None when not serving."""
        return None if self._server is None else tuple(self._server.server_address[:2])

    def close(self) -> None:
        """Stop the HTTP endpoint (idempotent)."""
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            if self._thread is not None:
                self._thread.join(timeout=5)
            self._server = self._thread = None

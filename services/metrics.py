"""Prometheus metrics of the whole CMCL service: one registry, one HTTP endpoint, fed by plain-dict reports.

Where it sits: `services/launch.py` (the supervisor, a single process) creates one `ServiceMetrics`, calls
`serve(port, host)` once, and passes every report an actor returns to `apply(report)` (or `try_apply`, which
returns the error text instead of raising). Actors never touch Prometheus: they build plain dicts of numbers,
strings and numpy arrays. deploy/prometheus.yml scrapes the endpoint; deploy/grafana/dashboards/cmcl.json
shows it. The endpoint binds 127.0.0.1 unless told otherwise (the compose file passes 0.0.0.0 inside its
private network) and uses its own `CollectorRegistry`, never prometheus-client's global one.

Report schema (version 1; every key optional unless stated; unknown keys are refused)::

    {"schema": 1,                  # if present, must equal SCHEMA_VERSION
     "source": "rollout-0",        # who sent it (str); keys the counter bookkeeping. Default "default".
     "role": "rollout",            # rollout | replay | teacher | icm | learner | ... : label of restarts
     "incarnation": "5f0c…",       # str/int, new in every actor __init__; a change counts one restart
     "resumed": False,             # True: the new incarnation restored its totals from a checkpoint
     "weight_version": 12,         # policy version this actor is using -> cmcl_weight_version_lag{actor=source}
     "replay": {"size": n, "capacity": n,                    # gauges (transitions)
                "inserts": N, "samples": N,                  # cumulative totals (transitions)
                "rejected": {"bad_shape": N, ...},           # cumulative totals per reason
                "difficulty": arr, "priority": arr,          # samples: normalised difficulty in [0,1], CI
                "kfold_priority": arr, "curiosity_priority": arr,   # samples: KP, CP
                "score_age": arr,                            # samples: learner updates since each score
                "score_coverage": x},                        # fraction of the buffer with teacher scores
     "curriculum": {"lambda": x},
     "teachers": {"0": {"steps": N, "scores": N, "loss": x}, ...},   # per teacher id, N cumulative
     "icm": {"steps": N, "scores": N, "loss": x},                    # scores: curiosity rewards returned
     "learner": {"updates": N, "weight_version": v,                  # v: the version last published
                 "losses": {"agent_0": {"critic": x, "actor": x}, ...}},
     "rollout": {"env_steps": N, "episodes": N,                      # cumulative totals
                 "finished": {"coverage": arr, "success": arr,       # one value per episode finished
                              "reward": {team: arr}, "win": {team: arr}}}}   # since the previous report

Counter rule (N above). Actors send cumulative totals since their process started; the supervisor keeps the last
total per (source, metric, labels) and adds the difference, so a repeated report adds nothing. When `incarnation`
changes, one restart of `role` is counted and, unless `resumed` is true, the source's remembered totals are
dropped (the new totals are added whole, even when larger than the old). With `resumed` true the totals continue
the old series: only the part above the last total seen is added. A total lower than the last one from the same
incarnation is an older report applied late (the supervisor applies replies in the order they become ready,
which is not the order they were sent) and adds nothing; from a report without an incarnation it means the actor
restarted and counts from zero: the whole new total is added (Prometheus' own reset rule).

Gauges are last-writer-wins (size, capacity, λ and coverage come from the one replay server). The rates
`cmcl_env_steps_per_second` / `cmcl_updates_per_second` are counter growth over supervisor time, refreshed by
`apply` at most every `rate_interval` seconds, or on demand by `update_rates(now)`.

Histogram rule (arr above): any array-like of finite numbers, any shape (flattened). Each report adds at most
`max_samples` (default 512) values per histogram, a uniform subsample drawn with the seeded generator when the
array is larger, so a report weighs the same whatever the buffer size and costs a bounded amount; bucket
counts are added in one vectorised step. Histogram `_count` therefore counts observed samples, not
transitions. Episode statistics ("finished") feed moving averages over the last `window` episodes (default 100,
ALGORITHM.md §6.3) exported as gauges.

Bad reports (not a mapping, unknown key, wrong type, NaN/inf, negative count, bad label) raise `ReportError`
naming the key path and value; nothing of that report is applied, `cmcl_metrics_reports_rejected_total{reason}`
counts it, and the endpoint keeps serving.
"""

from __future__ import annotations

import math
import re
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from numbers import Real
from typing import Any

import numpy as np
from prometheus_client import CollectorRegistry, Counter, Gauge, generate_latest, start_http_server
from prometheus_client.metrics_core import HistogramMetricFamily, Metric
from prometheus_client.registry import Collector
from prometheus_client.utils import floatToGoString

SCHEMA_VERSION = 1
DEFAULT_MAX_SAMPLES = 512
UNIT_BUCKETS = tuple(round(0.05 * i, 2) for i in range(1, 21))  # [0.05 .. 1.0]
CI_BUCKETS = tuple(round(0.1 * i, 1) for i in range(1, 16))  # [0.1 .. 1.5]
AGE_BUCKETS = (0, 1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000, 10000)
_LABEL_RE = re.compile(r"^[A-Za-z0-9_.:\-]{1,64}$")
_TOP_KEYS = {"schema", "source", "role", "incarnation", "resumed", "weight_version"}


HISTOGRAMS = {  # report key in "replay" -> (metric name, help, bucket upper bounds)
    "difficulty": ("cmcl_difficulty", "Normalised teacher difficulty of buffer samples (0-1).", UNIT_BUCKETS),
    "priority": ("cmcl_priority", "Curriculum index CI of buffer samples.", CI_BUCKETS),
    "kfold_priority": ("cmcl_kfold_priority", "K-fold priority KP of buffer samples.", UNIT_BUCKETS),
    "curiosity_priority": ("cmcl_curiosity_priority", "Curiosity priority CP of buffer samples.", UNIT_BUCKETS),
    "score_age": ("cmcl_teacher_score_age_updates", "Learner updates since each teacher score was computed.",
                  AGE_BUCKETS),
}


def _bounds(lo: float | None, hi: float | None) -> str:
    """'in [lo, hi]' with open ends shown as -inf / inf, for error messages."""
    return f"in [{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}]"


class ReportError(ValueError):
    """A report is malformed; `reason` is the rejection label, the message names the key path and value."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


class NumpyHistogram(Collector):
    """A label-less histogram whose bucket counts grow from whole numpy arrays (one searchsorted per call)."""

    def __init__(self, name: str, documentation: str, buckets: tuple[float, ...]):
        self.name, self.documentation = name, documentation
        self._upper = np.asarray([*sorted(float(b) for b in buckets), math.inf])
        self._counts = np.zeros(self._upper.size, dtype=np.int64)
        self._sum = 0.0
        self._lock = threading.Lock()

    def observe_many(self, values: np.ndarray) -> None:
        """Add finite `values` [n] to the buckets (bucket i counts upper[i-1] < v <= upper[i])."""
        idx = np.searchsorted(self._upper, values, side="left")
        counts = np.bincount(idx, minlength=self._upper.size)
        with self._lock:
            self._counts += counts
            self._sum += float(values.sum())

    def collect(self) -> Iterator[Metric]:
        """Yield the histogram with cumulative bucket counts."""
        with self._lock:
            cumulative = np.cumsum(self._counts)
            total = self._sum
        buckets = [(floatToGoString(le), float(c)) for le, c in zip(self._upper, cumulative, strict=True)]
        yield HistogramMetricFamily(self.name, self.documentation, buckets=buckets, sum_value=total)


@dataclass
class _SourceState:
    """What the supervisor remembers about one report source: incarnation and last cumulative totals."""

    incarnation: str | None
    totals: dict[tuple, float] = field(default_factory=dict)


class ServiceMetrics:
    """Every metric of the service in one registry, updated from actor reports (see the module docstring)."""

    def __init__(self, *, max_samples: int = DEFAULT_MAX_SAMPLES, window: int = 100, seed: int = 0,
                 rate_interval: float = 5.0, clock: Callable[[], float] = time.monotonic):
        for name, value in (("max_samples", max_samples), ("window", window)):
            if value < 1:
                raise ValueError(f"{name} must be >= 1, got {value!r}")
        self.registry = CollectorRegistry(auto_describe=True)
        self.max_samples, self.window, self.rate_interval, self._clock = max_samples, window, rate_interval, clock
        self._rng = np.random.default_rng(seed)
        self._lock = threading.Lock()
        self._sources: dict[str, _SourceState] = {}
        self._episode_windows: dict[tuple[str, str], np.ndarray] = {}
        self._published_version: int | None = None
        self._actor_versions: dict[str, int] = {}
        self._accumulated = {"env_steps": 0.0, "learner_updates": 0.0}
        self._rate_mark: tuple[float, float, float] | None = None
        self._server: Any = None
        self._thread: threading.Thread | None = None
        self._define()

    def _define(self) -> None:
        """Create every metric in the private registry."""
        r = self.registry
        g = lambda name, doc, labels=(): Gauge(name, doc, labels, registry=r)  # noqa: E731
        c = lambda name, doc, labels=(): Counter(name, doc, labels, registry=r)  # noqa: E731
        self.gauges = {
            "replay_size": g("cmcl_replay_size", "Transitions stored in the replay buffer."),
            "replay_capacity": g("cmcl_replay_capacity", "Capacity of the replay buffer in transitions."),
            "score_coverage": g("cmcl_teacher_score_coverage", "Fraction of the buffer with teacher scores (0-1)."),
            "lambda": g("cmcl_curriculum_lambda", "Curriculum factor lambda owned by the replay server."),
            "teacher_loss": g("cmcl_teacher_loss", "Last fit loss of each teacher critic.", ["teacher"]),
            "icm_loss": g("cmcl_icm_loss", "Last ICM training loss (inverse + forward)."),
            "learner_loss": g("cmcl_learner_loss", "Last learner loss per agent and kind.", ["agent", "kind"]),
            "weight_lag": g("cmcl_weight_version_lag",
                            "Policy versions the actor is behind the learner's last published weights.", ["actor"]),
            "coverage_rate": g("cmcl_coverage_rate", "Landmark cover rate at the final step, moving average."),
            "success_rate": g("cmcl_success_rate", "Fraction of episodes with all landmarks covered, moving avg."),
            "win_rate": g("cmcl_win_rate", "Episode win rate per team, moving average.", ["team"]),
            "episode_reward": g("cmcl_episode_reward", "Team episode return, moving average.", ["team"]),
            "updates_per_second": g("cmcl_updates_per_second", "Learner updates per second (recent)."),
            "env_steps_per_second": g("cmcl_env_steps_per_second", "Environment steps per second (recent)."),
        }
        self.counters = {
            "replay_inserts": c("cmcl_replay_inserts_total", "Transitions accepted by the replay server."),
            "replay_samples": c("cmcl_replay_samples_total", "Transitions sampled from the replay buffer."),
            "replay_rejected": c("cmcl_replay_rejected_total", "Inputs refused by the replay server.", ["reason"]),
            "teacher_steps": c("cmcl_teacher_steps_total", "Teacher critic fit steps.", ["teacher"]),
            "teacher_scores": c("cmcl_teacher_scores_total", "Transitions scored by each teacher.", ["teacher"]),
            "icm_steps": c("cmcl_icm_steps_total", "ICM training steps."),
            "curiosity_scores": c("cmcl_curiosity_scores_total", "Curiosity rewards computed by the ICM actor."),
            "learner_updates": c("cmcl_learner_updates_total", "Learner update steps (all agents at once)."),
            "env_steps": c("cmcl_env_steps_total", "Environment steps taken by rollout workers (per world)."),
            "episodes": c("cmcl_episodes_total", "Episodes finished by rollout workers."),
            "restarts": c("cmcl_actor_restarts_total", "Actor restarts seen as a new incarnation.", ["role"]),
            "reports": c("cmcl_metrics_reports_total", "Reports applied to the metrics endpoint."),
            "reports_rejected": c("cmcl_metrics_reports_rejected_total", "Reports refused.", ["reason"]),
        }
        self.histograms = {key: NumpyHistogram(*spec) for key, spec in HISTOGRAMS.items()}
        for hist in self.histograms.values():
            r.register(hist)

    def metric_names(self) -> frozenset[str]:
        """Names as exposed: gauges as is, counters with `_total`, histograms without the bucket suffixes."""
        names = set()
        for family in self.registry.collect():
            names.add(family.name + "_total" if family.type == "counter" else family.name)
        return frozenset(names)

    @staticmethod
    def _number(path: str, value: Any, *, lo: float | None = None, hi: float | None = None) -> float:
        """A finite real within [lo, hi], else ReportError."""
        if isinstance(value, bool) or not isinstance(value, Real):
            raise ReportError("bad_type", f"report key {path} must be a number, got {value!r}")
        x = float(value)
        if not math.isfinite(x):
            raise ReportError("bad_value", f"report key {path} must be finite, got {value!r}")
        if (lo is not None and x < lo) or (hi is not None and x > hi):
            raise ReportError("bad_value", f"report key {path} must be {_bounds(lo, hi)}, got {value!r}")
        return x

    @staticmethod
    def _label(path: str, value: Any) -> str:
        """A label value: str or int matching [A-Za-z0-9_.:-]{1,64}."""
        if isinstance(value, bool) or not isinstance(value, str | int | np.integer):
            raise ReportError("bad_type", f"report key {path} must be a string label, got {value!r}")
        text = str(value)
        if not _LABEL_RE.match(text):
            raise ReportError("bad_value", f"report key {path} is not a valid label ([A-Za-z0-9_.:-]{{1,64}}), "
                                           f"got {value!r}")
        return text

    @staticmethod
    def _mapping(path: str, value: Any, allowed: set[str] | None = None) -> Mapping:
        """A mapping whose keys (if `allowed`) are all known."""
        if not isinstance(value, Mapping):
            raise ReportError("bad_type", f"report key {path} must be a mapping, got {type(value).__name__}")
        if allowed is not None:
            unknown = sorted(str(k) for k in value if k not in allowed)
            if unknown:
                prefix = f"{path}." if path else ""
                raise ReportError("unknown_key", f"unknown report key {prefix}{unknown[0]} (known: {sorted(allowed)})")
        return value

    def _array(self, path: str, value: Any, lo: float | None = None, hi: float | None = None,
               subsample: bool = True) -> np.ndarray:
        """Finite float64 values [n] (flattened) within [lo, hi], subsampled to `max_samples` if asked."""
        try:
            arr = np.asarray(value, dtype=np.float64).ravel()
        except (TypeError, ValueError):
            raise ReportError("bad_type", f"report key {path} must be an array of numbers, "
                                          f"got {type(value).__name__}") from None
        bad = ~np.isfinite(arr)
        bad |= (arr < lo) if lo is not None else False
        bad |= (arr > hi) if hi is not None else False
        if bad.any():
            raise ReportError("bad_value", f"report key {path} must hold finite values {_bounds(lo, hi)}, got "
                                           f"{int(bad.sum())} bad of {arr.size}, e.g. {arr[bad][:3].tolist()}")
        if subsample and arr.size > self.max_samples:
            arr = self._rng.choice(arr, size=self.max_samples, replace=False)
        return arr

    def _plan(self, report: Any) -> dict[str, list]:
        """Validate `report` and turn it into operations; raises ReportError before anything is applied."""
        sections = {"replay": self._plan_replay, "curriculum": self._plan_curriculum,
                    "teachers": self._plan_teachers, "icm": self._plan_icm, "learner": self._plan_learner,
                    "rollout": self._plan_rollout}
        self._mapping("", report, _TOP_KEYS | set(sections))
        plan: dict[str, list] = {"counter": [], "gauge": [], "hist": [], "episodes": [], "meta": [], "published": []}
        if "schema" in report and report["schema"] != SCHEMA_VERSION:
            raise ReportError("bad_schema", f"report key schema must be {SCHEMA_VERSION}, got {report['schema']!r}")
        incarnation, version, resumed = report.get("incarnation"), report.get("weight_version"), report.get("resumed")
        if not (resumed is None or isinstance(resumed, bool)):
            raise ReportError("bad_type", f"report key resumed must be true or false, got {resumed!r}")
        plan["meta"].append((self._label("source", report.get("source", "default")),
                             self._label("role", report.get("role", "unknown")),
                             None if incarnation is None else self._label("incarnation", incarnation), bool(resumed),
                             None if version is None else int(self._number("weight_version", version, lo=0))))
        for name, planner in sections.items():
            if name in report:
                planner(plan, report[name])
        return plan

    def _count(self, plan: dict, metric: str, labels: tuple, path: str, value: Any) -> None:
        """Plan a cumulative-total counter update."""
        plan["counter"].append((metric, labels, self._number(path, value, lo=0)))

    def _gauge(self, plan: dict, gauge: str, labels: tuple, path: str, value: Any, **bounds: float | None) -> None:
        """Plan a gauge set."""
        plan["gauge"].append((gauge, labels, self._number(path, value, **bounds)))

    def _plan_replay(self, plan: dict, section: Any) -> None:
        hists = tuple(HISTOGRAMS)
        keys = {"size", "capacity", "inserts", "samples", "rejected", "score_coverage", *hists}
        section = self._mapping("replay", section, keys)
        for key, gauge, hi in (("size", "replay_size", None), ("capacity", "replay_capacity", None),
                               ("score_coverage", "score_coverage", 1)):
            if key in section:
                self._gauge(plan, gauge, (), f"replay.{key}", section[key], lo=0, hi=hi)
        for key in ("inserts", "samples"):
            if key in section:
                self._count(plan, f"replay_{key}", (), f"replay.{key}", section[key])
        for reason, value in self._mapping("replay.rejected", section.get("rejected", {})).items():
            label = self._label(f"replay.rejected.{reason}", reason)
            self._count(plan, "replay_rejected", (label,), f"replay.rejected.{label}", value)
        for key in hists:
            if key in section:
                plan["hist"].append((key, self._array(f"replay.{key}", section[key], lo=0)))

    def _plan_curriculum(self, plan: dict, section: Any) -> None:
        section = self._mapping("curriculum", section, {"lambda"})
        if "lambda" in section:
            self._gauge(plan, "lambda", (), "curriculum.lambda", section["lambda"], lo=0)

    def _plan_teachers(self, plan: dict, section: Any) -> None:
        for tid, entry in self._mapping("teachers", section).items():
            label = self._label(f"teachers.{tid}", tid)
            entry = self._mapping(f"teachers.{label}", entry, {"steps", "scores", "loss"})
            for key in ("steps", "scores"):
                if key in entry:
                    self._count(plan, f"teacher_{key}", (label,), f"teachers.{label}.{key}", entry[key])
            if "loss" in entry:
                self._gauge(plan, "teacher_loss", (label,), f"teachers.{label}.loss", entry["loss"])

    def _plan_icm(self, plan: dict, section: Any) -> None:
        section = self._mapping("icm", section, {"steps", "scores", "loss"})
        for key, metric in (("steps", "icm_steps"), ("scores", "curiosity_scores")):
            if key in section:
                self._count(plan, metric, (), f"icm.{key}", section[key])
        if "loss" in section:
            self._gauge(plan, "icm_loss", (), "icm.loss", section["loss"])

    def _plan_learner(self, plan: dict, section: Any) -> None:
        section = self._mapping("learner", section, {"updates", "weight_version", "losses"})
        if "updates" in section:
            self._count(plan, "learner_updates", (), "learner.updates", section["updates"])
        if "weight_version" in section:
            plan["published"].append(int(self._number("learner.weight_version", section["weight_version"], lo=0)))
        for agent, kinds in self._mapping("learner.losses", section.get("losses", {})).items():
            agent = self._label(f"learner.losses.{agent}", agent)
            for kind, value in self._mapping(f"learner.losses.{agent}", kinds).items():
                kind = self._label(f"learner.losses.{agent}.{kind}", kind)
                self._gauge(plan, "learner_loss", (agent, kind), f"learner.losses.{agent}.{kind}", value)

    def _plan_rollout(self, plan: dict, section: Any) -> None:
        section = self._mapping("rollout", section, {"env_steps", "episodes", "finished"})
        for key in ("env_steps", "episodes"):
            if key in section:
                self._count(plan, key, (), f"rollout.{key}", section[key])
        finished = self._mapping("rollout.finished", section.get("finished", {}),
                                 {"coverage", "success", "reward", "win"})
        for key in ("coverage", "success"):
            if key in finished:
                values = self._array(f"rollout.finished.{key}", finished[key], 0, 1, subsample=False)
                plan["episodes"].append((f"{key}_rate", "", values))
        for key, gauge, bounds in (("reward", "episode_reward", (None, None)), ("win", "win_rate", (0, 1))):
            for team, values in self._mapping(f"rollout.finished.{key}", finished.get(key, {})).items():
                team = self._label(f"rollout.finished.{key}.{team}", team)
                values = self._array(f"rollout.finished.{key}.{team}", values, *bounds, subsample=False)
                plan["episodes"].append((gauge, team, values))

    def apply(self, report: Mapping[str, Any]) -> None:
        """Validate and apply one actor report atomically; ReportError (counted) if it is malformed."""
        with self._lock:  # one report at a time (the subsampling generator is shared too)
            try:
                plan = self._plan(report)
            except ReportError as err:
                self.counters["reports_rejected"].labels(err.reason).inc()
                raise
            self._commit(plan)
            self.counters["reports"].inc()
            now = self._clock()
            if self._rate_mark is None or now - self._rate_mark[0] >= self.rate_interval:
                self._update_rates(now)

    def try_apply(self, report: Mapping[str, Any]) -> str | None:
        """Like `apply`, but return the error message of a malformed report instead of raising."""
        try:
            self.apply(report)
        except ReportError as err:
            return str(err)
        return None

    def _commit(self, plan: dict[str, list]) -> None:
        """Apply a validated plan (caller holds the lock)."""
        source, role, incarnation, resumed, version = plan["meta"][0]
        state = self._source_state(source, role, incarnation, resumed)
        for metric, labels, total in plan["counter"]:
            delta = self._delta(state, (metric, labels), total, resumed or incarnation is not None)
            if delta > 0:
                counter = self.counters[metric]
                (counter.labels(*labels) if labels else counter).inc(delta)
                if metric in self._accumulated:
                    self._accumulated[metric] += delta
        for gauge, labels, value in plan["gauge"]:
            metric = self.gauges[gauge]
            (metric.labels(*labels) if labels else metric).set(value)
        for name, values in plan["hist"]:
            self.histograms[name].observe_many(values)
        for gauge, team, values in plan["episodes"]:
            self._extend_window(gauge, team, values)
        if version is not None:
            self._actor_versions[source] = version
        for published in plan["published"]:
            self._published_version = published
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
        """Recompute env steps/s and updates/s from counter growth since the previous call."""
        with self._lock:
            self._update_rates(self._clock() if now is None else now)

    def _update_rates(self, now: float) -> None:
        steps, updates = self._accumulated["env_steps"], self._accumulated["learner_updates"]
        if self._rate_mark is not None and now > self._rate_mark[0]:
            t0, steps0, updates0 = self._rate_mark
            self.gauges["env_steps_per_second"].set((steps - steps0) / (now - t0))
            self.gauges["updates_per_second"].set((updates - updates0) / (now - t0))
        self._rate_mark = (now, steps, updates)

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

"""The metrics report schema (version 1) as code: frozen dataclasses, `parse_report` and `Report.to_dict`.

Where it sits: every actor call returns one report (a plain mapping of numbers, strings and numpy arrays, or a
`Report`); the supervisor hands it to `services.observability.metrics.ServiceMetrics.apply`, which parses it here before
anything is applied. `parse_report` is the one validator: every key is optional unless stated, unknown keys are
refused, and a bad value raises `ReportError(reason, message)` naming the dotted key path (``replay.size``,
``teachers.1.loss``, ``rollout.finished.reward.agent``) and the value. Reasons: ``bad_type``, ``bad_value``,
``unknown_key``, ``bad_schema`` (the labels of `cmcl_metrics_reports_rejected_total{reason}`).

Kinds of value in the field comments: N, a cumulative total since the actor's process started (float >= 0;
ServiceMetrics turns totals into counter increments); x, a gauge (finite float); arr, array-like of finite
numbers, any shape, flattened to float64 [n]; label, a str or int matching [A-Za-z0-9_.:-]{1,64}, kept as str.
A field left None is absent (`to_dict` omits it). Compare reports by their `to_dict()` (fields hold arrays).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from functools import partial
from numbers import Real
from typing import Any

import numpy as np

SCHEMA_VERSION = 1
# ReplayReport's sample fields, in the order they are validated and subsampled (the seeded draws follow it)
SAMPLE_KEYS = ("difficulty", "priority", "kfold_priority", "curiosity_priority", "score_age", "curiosity_age",
               "sample_age")
_LABEL_RE = re.compile(r"^[A-Za-z0-9_.:\-]{1,64}$")
_TOP_KEYS = {"schema", "source", "role", "incarnation", "resumed", "weight_version", "checkpoints_refused"}


class ReportError(ValueError):
    """A report is malformed; `reason` is the rejection label, the message names the key path and value."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


def _plain(value: Any) -> Any:
    """A section, a mapping of them or a leaf as plain data (sections via `to_dict`)."""
    if isinstance(value, _Section):
        return value.to_dict()
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    return value


class _Section:
    """Shared `to_dict` of the report dataclasses: the report keys of the fields that are not None."""

    def to_dict(self) -> dict[str, Any]:
        """This part of the report as the plain mapping `parse_report` reads back to an equal part."""
        return {f.metadata.get("key", f.name): _plain(getattr(self, f.name))
                for f in fields(self) if getattr(self, f.name) is not None}


# Every label value a labelled counter can take, so that the endpoint exports each series from the start (a panel
# shows 0, not "no data"): the reasons the replay server refuses an input for, the reasons a report is refused for
# (ReportError.reason), the roles of the actors.
REJECT_REASONS = ("bad_chunk", "duplicate", "invalid", "bad_feedback", "bad_scores", "log_truncated")
REPORT_REJECT_REASONS = ("bad_schema", "bad_type", "bad_value", "unknown_key")
ROLES = ("rollout", "replay", "learner", "teacher", "icm")


@dataclass(frozen=True)
class ReplayReport(_Section):
    """``replay``, sent by the replay server; the sample arrays hold one value per sampled buffer row."""

    size: float | None = None  # x >= 0: transitions stored
    capacity: float | None = None  # x >= 0: transitions storable
    inserts: float | None = None  # N: transitions accepted
    samples: float | None = None  # N: transitions sampled
    rejected: Mapping[str, float] | None = None  # {reason label: N}: inputs refused per reason (REJECT_REASONS)
    stale_scores: float | None = None  # N: score / |δ| updates dropped because their row was overwritten since
    score_coverage: float | None = None  # x in [0, 1]: fraction of the buffer with teacher scores
    difficulty: np.ndarray | None = None  # arr in [0, 1]: normalised teacher difficulty
    priority: np.ndarray | None = None  # arr >= 0: curriculum index CI
    kfold_priority: np.ndarray | None = None  # arr >= 0: K-fold priority KP
    curiosity_priority: np.ndarray | None = None  # arr >= 0: curiosity priority CP
    score_age: np.ndarray | None = None  # arr >= 0: learner updates since each row's teacher score
    curiosity_age: np.ndarray | None = None  # arr >= 0: learner updates since each row's curiosity score
    sample_age: np.ndarray | None = None  # arr >= 0: learner updates since insertion, of rows the learner sampled
    kp_branches: Mapping[str, float] | None = None  # {rising|falling|excluded: x in [0, 1]}: buffer share per branch
    fold_score_coverage: Mapping[str, float] | None = None  # {fold label: x in [0, 1]}: rows of fold scored
    sampling_ess: float | None = None  # x in [0, 1]: effective sample size of P / buffer size (1 = uniform)
    # per agent (label: agent index), cmcl.replay.diagnostics.replay_sampling_diagnostics, every agent's sampling
    # (uniform: 1):
    agent_sampling_ess: Mapping[str, float] | None = None  # {agent: x in [0, 1]}: ESS of the agent's P / buffer size
    reward_rows_sampled: Mapping[str, float] | None = None  # {agent: x in [0, 1]}: P-mass on rows with reward > 0
    reward_rows_buffer: Mapping[str, float] | None = None  # {agent: x in [0, 1]}: buffer share of rows with reward > 0


@dataclass(frozen=True)
class CurriculumReport(_Section):
    """``curriculum``, sent by the replay server (which owns λ)."""

    lam: float | None = field(default=None, metadata={"key": "lambda"})  # x >= 0, key "lambda": λ


@dataclass(frozen=True)
class FitReport(_Section):
    """``icm``, and each entry of ``teachers`` ({teacher id label: FitReport}): one model's fitting and scoring."""

    steps: float | None = None  # N: fit steps
    scores: float | None = None  # N: rows scored (teachers) / curiosity rewards returned (ICM)
    loss: float | None = None  # x: last fit loss (ICM: inverse + forward)


@dataclass(frozen=True)
class LearnerReport(_Section):
    """``learner``, sent by the learner."""

    updates: float | None = None  # N: update steps (all agents at once)
    weight_version: int | None = None  # int >= 0: the version last published
    losses: Mapping[str, Mapping[str, float]] | None = None  # {agent label: {kind label: x}}, kinds critic, actor,
    # critic_normalised (the critic's mean squared TD error over its targets' variance; absent when they had none),
    # and with maddpg.assignment_loss > 0 assignment, assignment_accuracy (services.roles.learner.last_losses)
    busy_s: float | None = None  # N: wall seconds inside update calls (the rest of the time it waited for batches)
    busy_cpu_s: float | None = None  # N: CPU seconds of those calls (the thread that ran them)


@dataclass(frozen=True)
class FinishedEpisodes(_Section):
    """``rollout.finished``: one value per episode finished since the previous report."""

    coverage: np.ndarray | None = None  # arr in [0, 1]: landmark cover rate at the final step (spread)
    success: np.ndarray | None = None  # arr in [0, 1]: all landmarks covered (spread)
    reward: Mapping[str, np.ndarray] | None = None  # {team label: arr}: team episode return
    win: Mapping[str, np.ndarray] | None = None  # {team label: arr in [0, 1]}: episode won (tag)
    # arr >= 0: the task curriculum stage it was played at (cmcl.rollout.task_curriculum)
    task_stage: np.ndarray | None = None


@dataclass(frozen=True)
class RolloutReport(_Section):
    """``rollout``, sent by each rollout worker."""

    env_steps: float | None = None  # N: environment steps (per world)
    episodes: float | None = None  # N: episodes finished
    finished: FinishedEpisodes | None = None


@dataclass(frozen=True)
class Report(_Section):
    """One actor report: who sent it, then one optional section per kind of role."""

    schema: int = SCHEMA_VERSION  # must equal SCHEMA_VERSION
    source: str = "default"  # label of the sender (e.g. "rollout-0"); keys the counter bookkeeping
    role: str = "unknown"  # label: rollout | replay | teacher | icm | learner | ... (of cmcl_actor_restarts_total)
    incarnation: str | None = None  # label, new in every actor __init__: a change counts one restart
    resumed: bool = False  # the new incarnation restored its totals from a checkpoint
    weight_version: int | None = None  # int >= 0: policy version in use (cmcl_weight_version_lag{actor=source})
    checkpoints_refused: float | None = None  # N: checkpoint files this incarnation refused when it started
    replay: ReplayReport | None = None
    curriculum: CurriculumReport | None = None
    teachers: Mapping[str, FitReport] | None = None
    icm: FitReport | None = None
    learner: LearnerReport | None = None
    rollout: RolloutReport | None = None


# ---------------------------------------------------------------------------------------------- validation
def _bounds(lo: float | None, hi: float | None) -> str:
    """'in [lo, hi]' with open ends shown as -inf / inf, for error messages."""
    return f"in [{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}]"


def _number(path: str, value: Any, lo: float | None = None, hi: float | None = None) -> float:
    """A finite real within [lo, hi] as float, else ReportError."""
    if isinstance(value, bool) or not isinstance(value, Real):
        raise ReportError("bad_type", f"report key {path} must be a number, got {value!r}")
    x = float(value)
    if not math.isfinite(x):
        raise ReportError("bad_value", f"report key {path} must be finite, got {value!r}")
    if (lo is not None and x < lo) or (hi is not None and x > hi):
        raise ReportError("bad_value", f"report key {path} must be {_bounds(lo, hi)}, got {value!r}")
    return x


def _label(path: str, value: Any) -> str:
    """A label value: str or int matching [A-Za-z0-9_.:-]{1,64}, as str."""
    if isinstance(value, bool) or not isinstance(value, str | int | np.integer):
        raise ReportError("bad_type", f"report key {path} must be a string label, got {value!r}")
    text = str(value)
    if not _LABEL_RE.match(text):
        raise ReportError("bad_value", f"report key {path} is not a valid label ([A-Za-z0-9_.:-]{{1,64}}), "
                                       f"got {value!r}")
    return text


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


def _array(path: str, value: Any, lo: float | None = None, hi: float | None = None) -> np.ndarray:
    """Finite float64 values [n] (flattened) within [lo, hi]."""
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
    return arr


def _numbers(path: str, section: Mapping, spec: tuple[tuple[str, float | None, float | None], ...]) -> dict:
    """{key: _number(path.key, section[key], lo, hi)} for each (key, lo, hi) of `spec` present, in spec order."""
    return {key: _number(f"{path}.{key}", section[key], lo, hi) for key, lo, hi in spec if key in section}


def _labelled(path: str, value: Any, parse: Any) -> dict[str, Any]:
    """{label: parse(path.label, entry)} of a mapping keyed by labels."""
    out = {}
    for key, entry in _mapping(path, value).items():
        label = _label(f"{path}.{key}", key)
        out[label] = parse(f"{path}.{label}", entry)
    return out


AGENT_SHARES = ("agent_sampling_ess", "reward_rows_sampled", "reward_rows_buffer")  # {agent label: x in [0, 1]}


def _parse_replay(section: Any) -> ReplayReport:
    """Validate ``replay``."""
    keys = {"size", "capacity", "inserts", "samples", "rejected", "stale_scores", "score_coverage", "kp_branches",
            "fold_score_coverage", "sampling_ess", *AGENT_SHARES, *SAMPLE_KEYS}
    section = _mapping("replay", section, keys)
    values: dict[str, Any] = _numbers("replay", section, (("size", 0, None), ("capacity", 0, None),
                                                           ("score_coverage", 0, 1), ("inserts", 0, None),
                                                           ("samples", 0, None), ("stale_scores", 0, None),
                                                           ("sampling_ess", 0, 1)))
    if "rejected" in section:
        values["rejected"] = _labelled("replay.rejected", section["rejected"], lambda p, v: _number(p, v, lo=0))
    for key in ("kp_branches", "fold_score_coverage", *AGENT_SHARES):
        if key in section:
            values[key] = _labelled(f"replay.{key}", section[key], lambda p, v: _number(p, v, lo=0, hi=1))
    values.update({key: _array(f"replay.{key}", section[key], lo=0) for key in SAMPLE_KEYS if key in section})
    return ReplayReport(**values)


def _parse_curriculum(section: Any) -> CurriculumReport:
    """Validate ``curriculum``."""
    section = _mapping("curriculum", section, {"lambda"})
    return CurriculumReport(lam=_numbers("curriculum", section, (("lambda", 0, None),)).get("lambda"))


_FIT_SPEC = (("steps", 0, None), ("scores", 0, None), ("loss", None, None))


def _parse_fit(path: str, entry: Any) -> FitReport:
    """Validate ``icm`` or one ``teachers.<id>`` entry."""
    entry = _mapping(path, entry, {"steps", "scores", "loss"})
    return FitReport(**_numbers(path, entry, _FIT_SPEC))


def _parse_learner(section: Any) -> LearnerReport:
    """Validate ``learner``."""
    section = _mapping("learner", section, {"updates", "weight_version", "losses", "busy_s", "busy_cpu_s"})
    values: dict[str, Any] = _numbers("learner", section, (("updates", 0, None), ("busy_s", 0, None),
                                                            ("busy_cpu_s", 0, None)))
    if "weight_version" in section:
        values["weight_version"] = int(_number("learner.weight_version", section["weight_version"], lo=0))
    if "losses" in section:
        values["losses"] = _labelled("learner.losses", section["losses"],
                                     lambda path, kinds: _labelled(path, kinds, _number))
    return LearnerReport(**values)


def _parse_finished(section: Any) -> FinishedEpisodes:
    """Validate ``rollout.finished``."""
    path = "rollout.finished"
    section = _mapping(path, section, {"coverage", "success", "reward", "win", "task_stage"})
    values = {key: _array(f"{path}.{key}", section[key], 0, 1) for key in ("coverage", "success") if key in section}
    if "task_stage" in section:
        values["task_stage"] = _array(f"{path}.task_stage", section["task_stage"], 0, None)
    for key, lo, hi in (("reward", None, None), ("win", 0, 1)):
        if key in section:
            values[key] = _labelled(f"{path}.{key}", section[key], lambda p, v, lo=lo, hi=hi: _array(p, v, lo, hi))
    return FinishedEpisodes(**values)


def _parse_rollout(section: Any) -> RolloutReport:
    """Validate ``rollout``."""
    section = _mapping("rollout", section, {"env_steps", "episodes", "finished"})
    values: dict[str, Any] = _numbers("rollout", section, (("env_steps", 0, None), ("episodes", 0, None)))
    if "finished" in section:
        values["finished"] = _parse_finished(section["finished"])
    return RolloutReport(**values)


_SECTIONS = {"replay": _parse_replay, "curriculum": _parse_curriculum,
             "teachers": lambda section: _labelled("teachers", section, _parse_fit),
             "icm": partial(_parse_fit, "icm"), "learner": _parse_learner, "rollout": _parse_rollout}


def parse_report(report: Any) -> Report:
    """Validate a report mapping (the schema above) into a `Report`; ReportError names the first bad key."""
    _mapping("", report, _TOP_KEYS | set(_SECTIONS))
    if "schema" in report and report["schema"] != SCHEMA_VERSION:
        raise ReportError("bad_schema", f"report key schema must be {SCHEMA_VERSION}, got {report['schema']!r}")
    incarnation, version, resumed = report.get("incarnation"), report.get("weight_version"), report.get("resumed")
    if not (resumed is None or isinstance(resumed, bool)):
        raise ReportError("bad_type", f"report key resumed must be true or false, got {resumed!r}")
    meta = {"source": _label("source", report.get("source", "default")),
            "role": _label("role", report.get("role", "unknown")),
            "incarnation": None if incarnation is None else _label("incarnation", incarnation),
            "resumed": bool(resumed),
            "weight_version": None if version is None else int(_number("weight_version", version, lo=0)),
            "checkpoints_refused": None if report.get("checkpoints_refused") is None else
            _number("checkpoints_refused", report["checkpoints_refused"], lo=0)}
    sections = {name: parse(report[name]) for name, parse in _SECTIONS.items() if name in report}
    return Report(**meta, **sections)

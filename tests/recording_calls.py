"""A scheduler that records what a real run's roles hand the replay server, read from the messages themselves.

`RecordingCalls` wraps the run's own scheduler (services.runtime.calls.InProcessCalls or RayCalls; installed through
`services.launch.run_service`'s `started` hook, so the run is otherwise untouched) and notes, in the order the
supervisor submits them, every `sample` reply of the replay server and every `Scores` it is given (`write`, and the
online critics' inside `learner_result`'s LearnerFeedback). The replay server runs one caller's calls in submission
order on both schedulers, so this order is the order in which it sampled and stored. `outcome()` reads the
recorded replies and arguments (ray.get on the service) after the run.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cmcl.replay.messages import LearnerBatch, LearnerFeedback, Scores


@dataclass
class Outcome:
    """What a run sampled and scored, in the replay server's order. events: ("sample", slots int64[K],
    generations int64[K]) or ("scores", column, slots int64[M], generations int64[M])."""

    events: list[tuple[Any, ...]] = field(default_factory=list)

    @property
    def columns(self) -> set[str]:
        """The score columns written."""
        return {e[1] for e in self.events if e[0] == "scores"}

    def sampled(self) -> list[tuple[int, int]]:
        """Every sampled (slot, generation), in order."""
        return [p for e in self.events if e[0] == "sample" for p in zip(e[1].tolist(), e[2].tolist(), strict=True)]

    def sampled_before_scored(self, column: str) -> set[tuple[int, int]]:
        """The sampled (slot, generation) pairs that no Scores of `column` had given a value before they were
        sampled."""
        scored: set[tuple[int, int]] = set()
        early: set[tuple[int, int]] = set()
        for e in self.events:
            if e[0] == "scores" and e[1] == column:
                scored.update(zip(e[2].tolist(), e[3].tolist(), strict=True))
            elif e[0] == "sample":
                early.update(p for p in zip(e[1].tolist(), e[2].tolist(), strict=True) if p not in scored)
        return early


class RecordingCalls:
    """The run's scheduler `calls`, noting the replay server's (`replay`) sample replies and the Scores it is
    given; everything else passes through unchanged."""

    def __init__(self, calls: Any, replay: Any):
        self.calls, self.replay, self.FAILED = calls, replay, calls.FAILED
        self.log: list[Any] = []  # refs of the sample replies and of the Scores / feedback arguments, in order

    def submit(self, handle: Any, method: str, *args: Any, returns: int = 1, retry: bool = False) -> Any:
        out = self.calls.submit(handle, method, *args, returns=returns, retry=retry)
        if handle is self.replay and method == "sample":
            self.log.append(out[0])
        elif handle is self.replay and method in ("write", "learner_result"):
            self.log.append(args[0])
        return out

    def wait(self, refs: Any, timeout: float) -> list[Any]:
        return self.calls.wait(refs, timeout)

    def get(self, ref: Any) -> Any:
        return self.calls.get(ref)

    def outcome(self) -> Outcome:
        out = Outcome()
        for ref in self.log:
            value = self.calls.get(ref)
            if isinstance(value, LearnerBatch):
                out.events.append(("sample", value.slots.ravel(), value.generations.ravel()))
            scores = value.scores if isinstance(value, LearnerFeedback) else value
            if isinstance(scores, Scores):
                out.events.append(("scores", scores.scorer.column, np.asarray(scores.slots),
                                   np.asarray(scores.generations)))
        return out


def recorded_run(config: Any, directory: Any, in_process: bool) -> tuple[dict[str, Any], Outcome]:
    """Train `config` into a new run directory `directory` on one scheduler (in this process, or on the Ray already
    initialised), recording it. Returns (the supervisor's summary, what it sampled and scored)."""
    from cmcl.config import config_from_dict
    from cmcl.run.rundir import RunDirectory
    from services.launch import run_service

    data = config.to_dict()
    data["run"] = {**data["run"], "dir": str(directory)}
    config = config_from_dict(data)
    recorders: list[RecordingCalls] = []

    def record(supervisor: Any, roles: Any) -> None:
        supervisor.calls = RecordingCalls(supervisor.calls, roles.replay)
        recorders.append(supervisor.calls)

    summary = run_service(config, RunDirectory.create(config.run.dir, config), progress=None, started=record,
                          in_process=in_process)
    return summary, recorders[0].outcome()

"""Health of the service's actors, as the supervisor sees it: which actor a call belongs to, hung calls, crash loops.

Where it sits: `services.runtime.supervisor.Supervisor` notes each call it submits (`CallWatch.submitted`) and each
reply (`done`); its services.runtime.failures.Failures acts on them. An actor whose oldest call has waited longer than
`service.call_timeout_s` is hung: the supervisor kills it (`ray.kill(no_restart=False)`), Ray restarts it and its
calls fail, which frees their slots. An actor other than a rollout worker that died for good (out of
`service.max_restarts`) ends the run with `ServiceFailed` naming the role, instead of a loop of failing calls; a
rollout worker out of restarts is replaced by a fresh one.
"""

from __future__ import annotations

import time
from typing import Any

# the actor that runs a tracked call, by the call's kind (every other kind is a call of the replay server)
OWNER = {"rollout_report": "rollout", "chunk": "rollout", "learner_report": "learner", "feedback": "learner",
         "teacher_report": "teacher", "teacher_scores": "teacher", "icm_report": "icm", "icm_scores": "icm",
         "online_scores": "learner"}
# the kinds of the replay server's replies that end a chain of work given to a role (its slot in the supervisor's
# calls in flight); "online": the online critics' scores, the learner's (ACL td_self)
WORK_KINDS = ("rollout", "learner", "teacher", "icm", "online")


ARGUMENT_LOST = "input arguments for this task could not be computed"  # Ray's text: an argument's producer died


class ServiceFailed(RuntimeError):
    """A role other than a rollout worker died for good: the run cannot go on."""


def owner(kind: str) -> str:
    """The role whose actor runs a call of this kind: rollout, learner, teacher, icm or replay."""
    return OWNER.get(kind, "replay")


def failed_role(kind: str, err: Exception) -> tuple[str, bool]:
    """(the role whose actor failed a call of `kind`, whether that actor itself died). A replay-server call whose
    argument (a chunk, feedback, scores) could not be computed failed because the producer died, not the replay."""
    if kind in WORK_KINDS and ARGUMENT_LOST in str(err):
        return ("learner" if kind == "online" else kind), False
    return owner(kind), True


def actor_key(kind: str, index: int) -> tuple[str, int]:
    """(role, actor index) of the actor that runs a call: rollout workers and teacher actors are indexed, the
    learner, the ICM and the replay server are single (index 0)."""
    role = owner(kind)
    return role, index if role in ("rollout", "teacher") else 0


def actor_of(roles: Any, role: str, index: int) -> Any:
    """The handle of the actor of `role` (index: which rollout worker / teacher actor)."""
    return {"rollout": lambda: roles.rollout[index], "learner": lambda: roles.learner,
            "teacher": lambda: roles.teachers[index], "icm": lambda: roles.icm, "replay": lambda: roles.replay}[role]()


def restartable(err: Exception) -> bool:
    """Whether Ray will restart the actor behind `err` (it says so in the error's message)."""
    return "restart" in str(err).lower() and "will not be restarted" not in str(err).lower()


def check_not_dead_for_good(role: str, err: Exception, max_restarts: int) -> None:
    """Raise ServiceFailed if `err` says the (non-rollout) actor of `role` will not be restarted."""
    if role != "rollout" and not restartable(err) and "died" in str(err).lower():
        raise ServiceFailed(f"the {role} actor died and will not be restarted (service.max_restarts={max_restarts} "
                            f"restarts used up): the run stops. Last error: {str(err).splitlines()[0]}")


class CallWatch:
    """Submission times of the calls in flight, to find hung actors. timeout_s <= 0 turns the check off.

    A call's wait includes the time it queues behind the replay server call it depends on (a learner update waits
    for its batch), so the timeout must be well above the slowest legitimate call (checkpoints included).
    """

    def __init__(self, timeout_s: float):
        self.timeout_s = float(timeout_s)
        self.since: dict[Any, float] = {}

    def submitted(self, ref: Any) -> None:
        self.since[ref] = time.monotonic()

    def done(self, ref: Any) -> None:
        self.since.pop(ref, None)

    def overdue(self, pending: dict[Any, tuple[str, int, int]], now: float | None = None) -> set[tuple[str, int]]:
        """(role, index) of every actor with a call in flight for longer than the timeout."""
        if self.timeout_s <= 0:
            return set()
        now = time.monotonic() if now is None else now
        return {actor_key(kind, index) for ref, (kind, index, _) in pending.items()
                if now - self.since.get(ref, now) > self.timeout_s}

    def restart_clock(self, pending: dict[Any, tuple[str, int, int]], actor: tuple[str, int]) -> None:
        """Count the wait of `actor`'s calls from now (after it was killed, until their failures arrive)."""
        now = time.monotonic()
        for ref, (kind, index, _) in pending.items():
            if actor_key(kind, index) == actor:
                self.since[ref] = now


class RecoveryClock:
    """Recovery times per role: from a call failing because its actor died to the next reply of that actor (its
    restarted incarnation). Seconds, monotonic clock; `times` = {role: [seconds, ...]} in order of recovery."""

    def __init__(self) -> None:
        self.failed_at: dict[tuple[str, int], float] = {}
        self.times: dict[str, list[float]] = {}

    def failed(self, actor: tuple[str, int], now: float | None = None) -> None:
        """An actor's call failed; the first failure of an outage starts its clock."""
        self.failed_at.setdefault(actor, time.monotonic() if now is None else now)

    def replied(self, actor: tuple[str, int], now: float | None = None) -> None:
        """An actor replied: if it was down, its outage ends here."""
        since = self.failed_at.pop(actor, None)
        if since is not None:
            self.times.setdefault(actor[0], []).append((time.monotonic() if now is None else now) - since)

"""Failures: what the supervisor does when a call fails or hangs, and the failure counts its summary reports.

Where it sits: `services.runtime.supervisor.Supervisor` owns one `Failures`. It notes each call it submits and each
reply in `watch` (services.runtime.health.CallWatch) and each reply of an actor in `recovery`
(services.runtime.health.RecoveryClock), and hands over every call that failed (`call_failed`), every role's save that
failed (`save_failed`) and every error the replay server reports (`replay_error`); `kill_hung` kills, for Ray to
restart, each actor with a call in flight longer than service.call_timeout_s. It touches the roles only to kill a hung
actor and to replace a rollout worker out of restarts (`Roles.make_rollout`); any other role dead for good ends the run
(services.runtime.health.ServiceFailed). Which actor a call belongs to and when an actor is dead for good are
services.runtime.health's.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

from cmcl.config import Config
from cmcl.io.write_failure import RunWriteError
from services.runtime.health import (
    WORK_KINDS,
    CallWatch,
    RecoveryClock,
    actor_key,
    actor_of,
    check_not_dead_for_good,
    failed_role,
    restartable,
)
from services.runtime.placement import Roles


def end_if_write_failure(err: Exception) -> None:
    """Raise the cause of a role's failed call when it is a write its device refused (RunWriteError: a full disk):
    a retry would meet it again, so the run ends, its files as they were (cmcl.run.flags.train_in_run says it)."""
    if isinstance(getattr(err, "cause", None), RunWriteError):
        raise err.cause from None


class Failures:
    """The failure bookkeeping of one run: `counts` (failed calls per role of the actor that ran them, and the replay
    server's errors per reason), `hung` (actors killed per role), the hung-call `watch` and the `recovery` clock."""

    def __init__(self, config: Config, roles: Roles):
        self.roles, self.max_restarts = roles, config.service.max_restarts
        self.counts: dict[str, int] = {}  # failed calls per role of the actor that ran them
        self.hung: dict[str, int] = {}  # actors killed for a call in flight longer than service.call_timeout_s
        self.watch = CallWatch(config.service.call_timeout_s)
        self.recovery = RecoveryClock()  # seconds from a dead actor's failed call to its next reply, per role

    def _count(self, key: str) -> None:
        self.counts[key] = self.counts.get(key, 0) + 1

    def replay_error(self, error: str) -> None:
        """The replay server reported an error in a reply (`ReplayStatus.error`): counted under its reason."""
        self._count(error.split(":")[0])

    def call_failed(self, kind: str, index: int, err: Exception,
                    inflight: Counter[tuple[str, int]]) -> tuple[str, bool]:
        """A call failed because an actor died: free its slot in `inflight` (Ray restarts the actor) or replace a
        rollout worker out of restarts; any other role out of restarts ends the run (`ServiceFailed`). Returns
        (the role whose actor failed, whether that actor itself died: `failed_role`)."""
        role, own_death = failed_role(kind, err)
        self._count(role)
        if own_death:
            self.recovery.failed(actor_key(kind, index))
        if kind in WORK_KINDS:
            inflight[(kind, index)] -= 1
        import ray  # failures only happen on the Ray scheduler (services.runtime.calls)

        if own_death and isinstance(err, ray.exceptions.ActorDiedError):
            check_not_dead_for_good(role, err, self.max_restarts)
            if kind == "rollout_report" and not restartable(err):
                self.roles.rollout[index] = self.roles.make_rollout(index)  # out of restarts: a fresh worker
        return role, own_death

    def save_failed(self, role: str, err: Exception) -> None:
        """A role's save failed (it keeps its previous checkpoint): counted; a role dead for good ends the run."""
        self._count(role)
        check_not_dead_for_good(role, err, self.max_restarts)

    def kill_hung(self, pending: dict[Any, tuple[str, int, int]]) -> None:
        """Kill (for Ray to restart) every actor with a call in `pending` in flight longer than
        service.call_timeout_s."""
        for role, index in self.watch.overdue(pending):
            import ray  # an overdue call is a Ray actor's (one process's calls are done when submitted)

            ray.kill(actor_of(self.roles, role, index), no_restart=False)
            self.hung[role] = self.hung.get(role, 0) + 1
            self.watch.restart_clock(pending, (role, index))

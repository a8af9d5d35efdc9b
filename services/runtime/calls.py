"""The two schedulers of one run: how the supervisor's calls reach the roles.

Where it sits: `services.runtime.supervisor.Supervisor` is the one loop of a run (Algorithm 1 as the pacing of
`cmcl.replay.pacing.Pacing` hands it out: docs/DESIGN.md "One runner, two schedulers"). It never calls a role
directly: it submits each call through one of these, and waits for and reads the replies through it.

* `RayCalls` (`--runner service`): each role is a Ray actor; a call is an actor task, its reply an object ref;
  calls overlap across actors and the supervisor forwards refs, never data.
* `InProcessCalls` (`--runner inline`): each role is the same class built as a plain object in this process
  (services.runtime.placement.build_roles); a call runs at once, to its end, and its reply is a `Done` holding the
  value. The replies are then taken in submission order, so a run is one deterministic sequence of the service's own
  calls: rollout chunk -> insert -> the teacher / ICM work and the learner updates its pacing allows -> their
  scores and |δ| written back. Nothing here imports Ray.

Both offer `submit(handle, method, *args, returns=1, retry=False)` (returns one ref, or a tuple of `returns` refs;
an argument may be a ref of an earlier call), `wait(refs, timeout)` (the refs whose calls are done, at least one
unless `timeout` s pass) and `get(ref)` (the value; a failed Ray call raises Ray's error).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any


class RayCalls:
    """Calls as Ray actor tasks (`handle.method.options(...).remote(*args)`). `FAILED`: the errors `get` raises for a
    call whose actor died or raised (the supervisor's failure handling: services.runtime.failures)."""

    def __init__(self) -> None:
        import ray

        self.FAILED = (ray.exceptions.RayActorError, ray.exceptions.RayTaskError, ray.exceptions.ObjectLostError)

    def submit(self, handle: Any, method: str, *args: Any, returns: int = 1, retry: bool = False) -> Any:
        """Submit one call; `retry`: Ray retries it until the actor answers (read-only calls only)."""
        options: dict[str, Any] = {}
        if returns != 1:
            options["num_returns"] = returns
        if retry:
            options["max_task_retries"] = -1
        call = getattr(handle, method)
        return (call.options(**options) if options else call).remote(*args)

    def wait(self, refs: Sequence[Any], timeout: float) -> list[Any]:
        """The refs that are done: waits up to `timeout` s for one, then takes every other already done."""
        import ray

        ready, rest = ray.wait(list(refs), num_returns=1, timeout=timeout, fetch_local=False)
        if ready and rest:
            more, _ = ray.wait(rest, num_returns=len(rest), timeout=0, fetch_local=False)
            ready += more
        return ready

    def get(self, ref: Any) -> Any:
        import ray

        return ray.get(ref)


class Done:
    """The reply of a call that has run in this process: its value (`InProcessCalls`). Compared by identity, so
    that each call's reply is its own key of the supervisor's pending calls."""

    __slots__ = ("value",)

    def __init__(self, value: Any):
        self.value = value


class InProcessCalls:
    """Calls run at once in this process, on the role objects themselves. An exception of a role propagates to the
    supervisor as it was raised (no actor restarts in one process: the run ends, checkpointed, as on the service when
    a role is out of restarts): `get` never fails, `FAILED` is empty."""

    FAILED: tuple[type[Exception], ...] = ()

    def submit(self, handle: Any, method: str, *args: Any, returns: int = 1, retry: bool = False) -> Any:
        value = getattr(handle, method)(*(a.value if isinstance(a, Done) else a for a in args))
        return tuple(Done(v) for v in value) if returns != 1 else Done(value)

    def wait(self, refs: Sequence[Any], timeout: float) -> list[Any]:
        return list(refs)

    def get(self, ref: Any) -> Any:
        return ref.value

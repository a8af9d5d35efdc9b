"""How many calls the supervisor gives each actor now, from the replay server's allowances (pure, no Ray).

Where it sits: `services.runtime.supervisor.Supervisor._issue` asks `calls_to_issue` after every reply, then submits
that many calls. The allowances are the replay server's pacing (`cmcl.replay.messages.PacingStatus`, the first fields of
every `ReplayStatus`: ALGORITHM.md §3.9, DESIGN.md data-flow step 7); the work already promised to calls in flight
is taken off them. At most CALLS_IN_FLIGHT calls per actor: one computing, one prefetched, so that while one
computes the replay server prepares the next (the learner's prefetch; the same for teachers and the ICM).
`HeldClock` counts the seconds in which the learner had no call at all, by what held it back.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence

from cmcl.config import Config
from cmcl.replay.messages import ReplayStatus

CALLS_IN_FLIGHT = 2  # per actor: one computing, one prefetched


def _calls(room: int, per_call: int, in_flight: int) -> int:
    """Calls while some room is left (each takes `per_call` of it) and fewer than CALLS_IN_FLIGHT are in flight."""
    n = 0
    while in_flight + n < CALLS_IN_FLIGHT and room - n * per_call > 0:
        n += 1
    return n


def calls_to_issue(status: ReplayStatus, in_flight: Mapping[tuple[str, int], int], config: Config,
                   rollout_workers: int, teacher_groups: Sequence[Sequence[int]], icm: bool,
                   rollouts: bool = True, online_critics: bool = False) -> Counter[tuple[str, int]]:
    """Calls to submit per (role, actor index), role in rollout / learner / teacher / icm / online.

    status: the replay server's newest (allowances, episodes stored so far); in_flight: calls in flight per
    (role, index); teacher_groups: the folds of each teacher actor; icm: whether there is an ICM actor;
    rollouts=False: no rollout calls (the episode target is reached); online_critics: the learner hosts the
    online critics' scorer (ACL td_self), given one call when the updates wait for scores and none is in flight
    (rows it has not scored: carried or restored ones; the supervisor has it score every chunk at insertion). A
    rollout call is one chunk of env.num_envs whole episodes (env.num_envs × env.episode_length transitions) and
    never collects more than run.episodes; a learner call is service.updates_per_call updates; a teacher / ICM call
    service.fit_steps_per_call fit steps.
    """
    svc, env = config.service, config.env
    calls: Counter[tuple[str, int]] = Counter()
    chunk = env.num_envs * env.episode_length
    chunks_in_flight = sum(in_flight.get(("rollout", w), 0) for w in range(rollout_workers))
    inserts_room = status.allowed_inserts - chunk * chunks_in_flight
    episodes_room = config.run.episodes - status.episodes - env.num_envs * chunks_in_flight
    for w in range(rollout_workers):
        while (rollouts and in_flight.get(("rollout", w), 0) + calls[("rollout", w)] < CALLS_IN_FLIGHT
               and inserts_room >= chunk and episodes_room > 0):
            calls[("rollout", w)] += 1
            inserts_room -= chunk
            episodes_room -= env.num_envs
    learner_in_flight = in_flight.get(("learner", 0), 0)
    calls[("learner", 0)] = _calls(status.allowed_updates - svc.updates_per_call * learner_in_flight,
                                   svc.updates_per_call, learner_in_flight)
    steps = svc.fit_steps_per_call
    for k, folds in enumerate(teacher_groups):
        busy = in_flight.get(("teacher", k), 0)
        calls[("teacher", k)] = _calls(min(status.teacher_allowed[f] for f in folds) - steps * busy, steps, busy)
    if icm:
        busy = in_flight.get(("icm", 0), 0)
        calls[("icm", 0)] = _calls(status.icm_allowed - steps * busy, steps, busy)
    if online_critics:
        calls[("online", 0)] = int(status.updates_held_by == "scores" and not in_flight.get(("online", 0), 0))
    return calls


class HeldClock:
    """Seconds of the supervisor's loop in which the learner had no call in flight, by why (`seconds`).

    `tick(now, learner_calls, status)` once per round of the loop, after its calls are issued: the time since the
    previous tick goes to the state the previous tick saw (the loop changes nothing while it waits for replies).
    A state is None (a learner call in flight), the status's `updates_held_by` ("warmup", "env_steps", "scores"),
    or "other" (no call although updates are allowed: the episode target is reached, or a call failed);
    `tick(..., during="checkpoint")` before a checkpoint counts its drain and saves as "checkpoint".
    `seconds` holds every reason from the start (0.0), so a reader in another thread sees a fixed set of keys.
    """

    REASONS = ("warmup", "env_steps", "scores", "checkpoint", "other")

    def __init__(self) -> None:
        self.seconds: dict[str, float] = dict.fromkeys(self.REASONS, 0.0)
        self._last: tuple[float, str | None] | None = None

    def tick(self, now: float, learner_calls: int, status: ReplayStatus, during: str | None = None) -> None:
        if self._last is not None and self._last[1] is not None:
            self.seconds[self._last[1]] += max(0.0, now - self._last[0])
        state = during or (None if learner_calls > 0 else (status.updates_held_by or "other"))
        self._last = (now, state)

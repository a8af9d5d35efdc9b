"""Ray placement policy: which actors a run needs, how many CPUs they ask for, and starting them.

Where it sits: `services.launch` calls `create_roles(config, run_dir)` once; the supervisor then drives the
returned `Roles`. The pure core (cmcl/) knows nothing of actors or CPUs: every placement decision (teacher folds
per actor, the CPU budget, the feasibility check) lives here. Ray itself is imported only by `create_roles`, so
the policy functions can be used and tested without a cluster.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from cmcl.config import Config
from cmcl.replay.messages import CURIOSITY, DIFFICULTY, ONLINE_TD, Scorer
from cmcl.run.rundir import RunDirectory
from cmcl.scorers.scoring import online_critics_score
from cmcl.system import layout_of
from services.roles.icm import ICMWorker
from services.roles.learner import Learner
from services.roles.replay_server import ReplayServer
from services.roles.rollout import RolloutWorker
from services.roles.teachers import TeacherWorker

ROLLOUT_RESOURCE_SHARE = 0.01  # units of service.rollout_resource each rollout worker requires


class InfeasibleResources(RuntimeError):
    """The roles ask for more CPUs than the cluster has."""


def teacher_groups(config: Config, cluster_cpus: float | None = None) -> list[list[int]]:
    """Fold indices hosted by each teacher actor: near-equal groups, fold i in group i mod actors.

    The number of actors is service.teacher_actors, or when that is 0 (automatic) K = teachers.num_folds if the
    cluster has at least 2K CPUs (`cluster_cpus`; None counts as enough), else 1 (one actor stacks every fold).
    """
    k = config.teachers.num_folds
    auto = k if cluster_cpus is None or cluster_cpus >= 2 * k else 1
    actors = min(k, config.service.teacher_actors or auto)
    return [list(range(k))[i::actors] for i in range(actors)]


def required_cpus(config: Config, cluster_cpus: float | None = None) -> float:
    """CPUs the roles of `config` request in total (service.*_cpus summed over the actors started)."""
    s, teams = config.service, config.teams.values()
    total = s.rollout_workers * s.rollout_cpus + s.learner_cpus + s.replay_cpus
    if any(t.uses_teachers for t in teams):
        total += len(teacher_groups(config, cluster_cpus)) * s.teacher_cpus
    if config.trains_icm:
        total += s.icm_cpus
    return total


@dataclass(frozen=True)
class ScorerRole:
    """One scorer as the supervisor drives it: its calls' kind ("teacher", "icm", "online": the online critics the
    learner hosts) and actor index, the actor's handle, the Scorer it is (`ReplayServer.work`'s argument) and whether
    its `score` call takes the learner's published weights (the teachers' regression targets)."""

    kind: str
    index: int
    handle: Any
    scorer: Scorer
    weights: bool = False


@dataclass
class Roles:
    """Handles of every actor, plus how to make a replacement for a rollout worker. `online_critics`: the learner
    hosts the online critics' scorer (ACL td_self)."""

    replay: Any
    learner: Any
    rollout: list[Any]
    teachers: list[Any]
    icm: Any | None
    teacher_groups: list[list[int]]
    make_rollout: Callable[[int], Any] = field(repr=False, default=None)
    online_critics: bool = False

    @property
    def scorers(self) -> list[ScorerRole]:
        """Every scorer of the run, in the order their calls are issued: the teacher groups, the ICM, the online
        critics."""
        teachers = [ScorerRole("teacher", k, t, Scorer(DIFFICULTY, tuple(folds)), weights=True)
                    for k, (t, folds) in enumerate(zip(self.teachers, self.teacher_groups, strict=True))]
        icm = [ScorerRole("icm", 0, self.icm, Scorer(CURIOSITY))] if self.icm is not None else []
        return [*teachers, *icm, *([self.online] if self.online_critics else [])]

    @property
    def online(self) -> ScorerRole:
        """The online critics' scorer, hosted by the learner (ACL td_self; a run uses it only with online_critics)."""
        return ScorerRole("online", 0, self.learner, Scorer(ONLINE_TD))


def resumed_episodes(run_dir: RunDirectory) -> int:
    """The episodes a resumed run had logged at its last checkpoint (0 for a new run, or one without it)."""
    import json

    path = run_dir.supervisor_counters
    try:
        return int(json.loads(path.read_text())["episodes_logged"]) if path.exists() else 0
    except (ValueError, KeyError, OSError):
        return 0


def create_roles(config: Config, run_dir: RunDirectory, in_process: bool = False) -> Roles:
    """Start every role: as a restartable Ray actor with fractional CPUs (after a feasibility check), or, with
    `in_process`, as the same class built as a plain object in this process (`--runner inline`:
    services.runtime.calls.InProcessCalls calls it), with the same seeds and checkpoint files."""
    s, seed, paths = config.service, config.run.seed, run_dir.service_paths()
    if in_process:  # one process is one core: every teacher fold in one stacked ensemble (teacher_groups)
        available, cfg = 1.0, config

        def actor(cls: type, cpus: float, resources: dict[str, float] | None = None) -> Callable[..., Any]:
            return cls
    else:
        import ray  # only here: the policy above needs no cluster

        available = ray.cluster_resources().get("CPU", 0.0)
        need = required_cpus(config, available)
        if need > available + 1e-9:
            raise InfeasibleResources(f"the roles request {need:.2f} CPUs (service.*_cpus) but the cluster has "
                                      f"{available:g}; lower service.rollout_workers or the per-role CPU requests")
        cfg = config.to_dict()  # configs cross process boundaries as plain dicts, re-validated on arrival

        def actor(cls: type, cpus: float, resources: dict[str, float] | None = None) -> Callable[..., Any]:
            return ray.remote(num_cpus=cpus, resources=resources or {}, max_restarts=s.max_restarts,
                              max_task_retries=0)(cls).remote

    rollout_resources = {s.rollout_resource: ROLLOUT_RESOURCE_SHARE} if s.rollout_resource else None

    resumed_at = resumed_episodes(run_dir)

    def make_rollout(w: int):
        return actor(RolloutWorker, s.rollout_cpus, rollout_resources)(cfg, w, seed * 1000 + w, resumed_at,
                                                                     str(paths["teacher"] / f"rollout_{w}.json"))

    teams = config.teams.values()
    groups = teacher_groups(config, available)
    teachers = []
    if any(t.uses_teachers for t in teams):
        teachers = [actor(TeacherWorker, s.teacher_cpus)(
            cfg, folds, seed * 1000 + 100 + i, str(paths["teacher"] / f"teacher_{'-'.join(map(str, folds))}.pt"))
            for i, folds in enumerate(groups)]
    icm = None
    if config.trains_icm:
        icm = actor(ICMWorker, s.icm_cpus)(cfg, seed * 1000 + 200, str(paths["icm"]))
    return Roles(replay=actor(ReplayServer, s.replay_cpus)(cfg, str(paths["replay"]), seed),
                 learner=actor(Learner, s.learner_cpus)(cfg, seed, str(paths["learner"])),
                 rollout=[make_rollout(w) for w in range(s.rollout_workers)], teachers=teachers, icm=icm,
                 teacher_groups=groups if teachers else [], make_rollout=make_rollout,
                 online_critics=online_critics_score(layout_of(config)))

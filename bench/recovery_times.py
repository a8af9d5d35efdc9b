"""Recovery times of each role of the service after a real SIGKILL, on the embedded Ray.

For each role (rollout worker, replay server, learner, teacher actor, ICM actor) one small CMCL run is trained, and
the role's process, found in Ray's GCS actor table, is SIGKILLed --kills times, each time once the incarnation
before has replied. Two times per kill:

* kill -> back: from the SIGKILL to the first reply of the restarted incarnation (what a user waits);
* detected -> back: the supervisor's own figure (`recovery_s` of its summary), from the first failed call to the
  next reply of that actor.

Every run must still end at its exact episode target with each transition stored once; the script says so per
role. Prints one table row per role (median and max over its kills).

    python bench/recovery_times.py --kills 3
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cmcl.config import config_from_dict, preset  # noqa: E402
from cmcl.run.rundir import RunDirectory  # noqa: E402
from services.observability.metrics import ServiceMetrics  # noqa: E402
from services.runtime.placement import create_roles  # noqa: E402
from services.runtime.supervisor import Supervisor  # noqa: E402
from tests.faults import sigkill_actor  # noqa: E402

SMALL = {"env": {"num_envs": 4}, "maddpg": {"batch_size": 16, "warmup": 96, "hidden": 32},
         "replay": {"capacity": 600}, "teachers": {"batch_size": 16, "hidden": 32, "num_folds": 3},
         "icm": {"batch_size": 16},
         "service": {"updates_per_call": 8, "fit_steps_per_call": 4, "score_rows_per_call": 256, "metrics_port": 0,
                     "checkpoint_every_s": 3600.0}}
REPLY_OF = {"rollout": ("rollout_report",), "learner": ("learner_report",), "teacher": ("teacher_report",),
            "icm": ("icm_report",), "replay": ("rollout", "learner", "teacher", "icm")}  # the replay's status replies


def config_for(path: Path, episodes: int, kills: int) -> Any:
    """A small CMCL config with enough restarts for `kills` kills."""
    data = preset("cmcl", "spread").to_dict()
    for section, values in SMALL.items():
        data[section].update(values)
    data["service"]["max_restarts"] = kills + 1
    data["run"].update(dir=str(path), episodes=episodes, smoothing_window=8)
    return config_from_dict(data)


def measure(role: str, kills: int, episodes: int, workdir: Path) -> dict[str, Any]:
    """Train one run with `kills` SIGKILLs of `role`; returns the times and the end-of-run invariants."""
    config = config_for(workdir / role, episodes, kills)
    run_dir = RunDirectory.create(config.run.dir, config)
    roles = create_roles(config, run_dir)
    supervisor = Supervisor(config, run_dir, roles, ServiceMetrics(), progress=None)
    handle = {"rollout": roles.rollout[0], "learner": roles.learner, "teacher": roles.teachers[0],
              "icm": roles.icm, "replay": roles.replay}[role]
    apply, killed, back, seen = supervisor._apply, [], [], set()

    def apply_then_kill(kind, index, value, *number):
        apply(kind, index, value, *number)
        if kind not in REPLY_OF[role] or (role in ("rollout", "teacher") and index != 0):
            return
        incarnation = value["incarnation"] if role == "replay" else value.incarnation
        if incarnation in seen:
            return
        seen.add(incarnation)
        if killed and len(back) < len(killed):
            back.append(time.monotonic() - killed[-1][1])
        if len(killed) < kills:
            killed.append(sigkill_actor(handle, exclude=frozenset(pid for pid, _ in killed)))

    supervisor._apply = apply_then_kill
    summary = supervisor.run()
    import ray

    for actor in (roles.replay, roles.learner, *roles.rollout, *roles.teachers, *([roles.icm] if roles.icm else [])):
        ray.kill(actor)
    return {"role": role, "kills": len(killed), "kill_to_back_s": back,
            "detected_to_back_s": summary["recovery_s"].get(role, []),
            "exact": summary["episodes"] == episodes and summary["env_steps"] == episodes * config.env.episode_length}


def row(result: dict[str, Any]) -> str:
    """One markdown row: median and max of both times over the kills."""
    def stat(values: list[float]) -> str:
        return f"{np.median(values):.2f} / {max(values):.2f}" if values else "none"
    return (f"| {result['role']} | {result['kills']} | {len(result['kill_to_back_s'])} | "
            f"{stat(result['kill_to_back_s'])} | {stat(result['detected_to_back_s'])} | "
            f"{'yes' if result['exact'] else 'NO'} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--kills", type=int, default=3)
    parser.add_argument("--episodes", type=int, default=160)
    parser.add_argument("--roles", nargs="+", default=list(REPLY_OF), choices=list(REPLY_OF))
    args = parser.parse_args()
    import ray

    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    print("| role | kills | recoveries seen | kill -> back s (median / max) | detected -> back s (median / max) | "
          "exact episode and env-step counts |\n| --- | --- | --- | --- | --- | --- |")
    with tempfile.TemporaryDirectory() as tmp:
        for role in args.roles:
            print(row(measure(role, args.kills, args.episodes, Path(tmp))), flush=True)
    ray.shutdown()


if __name__ == "__main__":
    main()

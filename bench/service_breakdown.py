"""Where the seconds of a `make run` go: the CPU each role of the service uses, and the learner's time split.

First, in this process and before Ray starts, one inline MADDPG update and one inline CMCL update are timed
(`inline_update_seconds` of bench/learner_throughput.py: the default presets' filled loops, interleaved rounds,
median, torch on one thread): what one core gives. Then the service runs as `make run` starts it (the Makefile's
`run:` target: configs/spread_maddpg.toml (--config: another), run.stop_coverage=0.9, an embedded Ray sized to the
machine, the reaper, the metrics endpoint; run.max_seconds = --seconds instead of 300; no held-out evaluation
afterwards).
A thread samples every second the CPU seconds (user + system, /proc via psutil) of every process this one started,
the machine's CPU times, and the service's counters. Processes are named by role: the actors by their own
`os.getpid()` (asked once before training), the rest by process name (raylet, gcs_server, dashboard, agents, log
monitor, idle Ray workers, the reaper); this process is the driver, which runs the supervisor (the sampler's own
CPU is taken off it and shown apart). The sampler and its CPU arithmetic are bench/breakdown_sampling.py; the
table and summary are printed by bench/breakdown_table.py.

The window runs from the first sample after the learner's first update (the end of the warm-up) to the end of the
budget (the final cut, checkpoint and Ray's shutdown are left out). Per role: CPU seconds in the window, cores
(CPU s / window s) and the share of all the machine's cores. For the learner, its time split from its own counters
(`LearnerReport.busy_s` / `busy_cpu_s`: wall and CPU seconds inside update calls) and the supervisor's
`HeldClock` (seconds with no learner call at all, by what the replay server's pacing held it back for: env steps,
scores, a checkpoint): computing vs waiting, and waiting for data vs for scores vs with a call in flight (its
batch being sampled / sent, or its feedback being written).

Run: .venv/bin/python bench/service_breakdown.py [--seconds 120] [--set k=v ...] [--inline-rounds 7]
     [--out lab/results/service_breakdown/make_run.json]
Output: the inline costs, a table (one row per role, then totals: the service, the machine, the rest of the
machine = other sessions), the learner's split, a summary ("the learner ran X updates/s where one core alone gives
Y"), and the JSON of all numbers with provenance. Read the table's `cores` as "of one core" (2.0 = both cores busy);
`share` is of all cores together; `ms/upd` is the role's CPU milliseconds per learner update in the window. CPU
seconds are those the processes got, on a shared machine: a role that waited for the CPU shows as less CPU, not as
more wall time (the learner's "computing" wall minus CPU shows that wait).
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import sys
from pathlib import Path
from typing import Any

import psutil

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.breakdown_sampling import Sampler, core_shares, cpu_between  # noqa: E402
from bench.breakdown_table import print_summary, print_table  # noqa: E402
from cmcl.run.provenance import LoadSampler, provenance  # noqa: E402

DEFAULT_SECONDS = 120
DEFAULT_OUT = "lab/results/service_breakdown/make_run.json"
MAKE_RUN = ["run.stop_coverage=0.9"]  # the Makefile's `run:` settings besides run.dir and run.max_seconds (and
# its `--metrics-port`: the bench takes a free port, as the tests do)
# Ray's own processes, by a fragment of their command line (first match wins), and the label of their row
RAY_PROCESSES = (("raylet", "raylet"), ("gcs_server", "gcs_server"), ("dashboard/agent.py", "dashboard agent"),
                 ("ray::DashboardAgent", "dashboard agent"), ("dashboard.py", "dashboard"),
                 ("RuntimeEnvAgent", "runtime env agent"), ("runtime_env/agent", "runtime env agent"),
                 ("log_monitor", "log monitor"), ("autoscaler/_private/monitor", "monitor"),
                 ("ray::IDLE", "idle Ray workers"))
# an actor's process title (ray::<Class>[.<method>]) -> its role, for actor processes whose pid was not asked
ACTOR_CLASSES = {"Learner": "learner", "ReplayServer": "replay server", "RolloutWorker": "rollout worker",
                 "TeacherWorker": "teachers", "ICMWorker": "ICM"}
# the groups of the summary, by role label prefix
GROUPS = (("learner", "learner"), ("teachers", "scoring (teachers + ICM)"), ("ICM", "scoring (teachers + ICM)"),
          ("rollout worker", "rollout workers"), ("replay server", "replay server"),
          ("driver", "driver (supervisor)"), ("reaper", "reaper"), ("bench sampler", "bench sampler"))


# ----------------------------------------------------------------------------- pure helpers (tested)
def role_of_process(cmdline: str, actor_roles: dict[int, str], pid: int) -> str:
    """The role label of a process: its actor role when its pid was asked (`actor_roles`), else by its command
    line: an actor's title (ray::Learner.update -> "learner"), one of Ray's own processes (RAY_PROCESSES), the
    reaper (services.runtime.reaper), else "other Ray worker" (ray::...) or "other: <first word>"."""
    if pid in actor_roles:
        return actor_roles[pid]
    if cmdline.startswith("ray::"):
        cls = cmdline[5:].split(".")[0].split()[0] if len(cmdline) > 5 else ""
        if cls in ACTOR_CLASSES:
            return ACTOR_CLASSES[cls] + " (pid not asked)"
    for fragment, label in RAY_PROCESSES:
        if fragment in cmdline:
            return label
    if "services.runtime.reaper" in cmdline:
        return "reaper"
    if cmdline.startswith("ray::"):
        return "other Ray worker"
    return "other: " + (Path(cmdline.split()[0]).name if cmdline.split() else "?")


def group_of(role: str) -> str:
    """The summary group of a role label (GROUPS by prefix; anything else is Ray's own)."""
    return next((group for prefix, group in GROUPS if role.startswith(prefix)), "Ray's own processes")


def learner_split(window_s: float, busy_s: float, busy_cpu_s: float, held: dict[str, float]) -> dict[str, float]:
    """The learner's wall clock over a window: `computing_s` (inside update calls; of it `computing_cpu_s` on the CPU
    and `computing_off_cpu_s` descheduled), `idle_s` = the rest, of it `held_<reason>_s` with no call at all (the
    supervisor's HeldClock) and `waiting_with_call_s` = idle minus those (a call in flight: its batch being sampled
    and sent, or its feedback being written). Shares of the window as `*_share`. Held time above the idle time
    (the two clocks are read a second apart) is scaled down to it."""
    idle = max(0.0, window_s - busy_s)
    held_total = sum(held.values())
    scale = min(1.0, idle / held_total) if held_total > 0 else 1.0
    out = {"window_s": window_s, "computing_s": busy_s, "computing_cpu_s": busy_cpu_s,
           "computing_off_cpu_s": max(0.0, busy_s - busy_cpu_s), "idle_s": idle}
    out.update({f"held_{reason}_s": seconds * scale for reason, seconds in held.items()})
    out["waiting_with_call_s"] = max(0.0, idle - held_total * scale)
    out.update({key.removesuffix("_s") + "_share": value / window_s for key, value in list(out.items())
                if key != "window_s"})
    return out


# ----------------------------------------------------------------------------- the run
def _actor_pid(_actor: Any) -> int:
    return os.getpid()


def actor_roles(roles: Any) -> dict[int, str]:
    """{pid: role label} of every actor, asked of each actor once (`__ray_call__`)."""
    import ray

    named = [(roles.learner, "learner"), (roles.replay, "replay server"),
             *((w, f"rollout worker {i}") for i, w in enumerate(roles.rollout)),
             *((t, "teachers (folds " + ",".join(map(str, folds)) + ")")
               for t, folds in zip(roles.teachers, roles.teacher_groups, strict=True)),
             *([(roles.icm, "ICM")] if roles.icm is not None else [])]
    pids = ray.get([handle.__ray_call__.remote(_actor_pid) for handle, _ in named])
    return {int(pid): label for pid, (_, label) in zip(pids, named, strict=True)}


def run_service(config: Any, run: Any, seconds: float) -> tuple[Sampler, dict[int, str], dict[str, Any]]:
    """The service as `make run` runs it (the reaper, the embedded Ray, then `services.launch.run_service`: metrics
    endpoint, the roles, the supervisor), sampled by a `Sampler` until the budget ends. Returns (sampler, actor
    roles, run summary)."""
    from services import launch
    from services.runtime.reaper import start_reaper

    watched: dict[str, Any] = {}

    def started(supervisor: Any, roles: Any) -> None:
        watched["actors"] = actor_roles(roles)
        watched["sampler"] = Sampler(supervisor, supervisor.clock.started + seconds - 0.05)
        watched["sampler"].start()

    start_reaper()
    launch.start_ray(None, None)
    launch.unblock_stop_signals()
    try:
        summary = launch.run_service(config, run, progress=None, started=started)
        watched["sampler"].join()
    finally:
        with launch.stderr_to(run.path / "ray_shutdown.log"):
            launch.stop_ray()
    return watched["sampler"], watched["actors"], summary


def breakdown(sampler: Sampler, actors: dict[int, str], cores: int) -> dict[str, Any]:
    """Rows per role, totals and the learner's split over the window (module docstring)."""
    first = next((s for s in sampler.samples if s.updates > 0), None)
    if first is None:
        raise RuntimeError("the learner never updated within the budget: raise --seconds")
    last = sampler.samples[-1]
    t0, t1 = first.t, last.t
    window = t1 - t0
    if window <= 0:
        raise RuntimeError("no sample after the warm-up: raise --seconds")
    me = os.getpid()
    sampler_cpu = cpu_between(sampler.own_cpu, t0, t1)
    rows: dict[str, dict[str, Any]] = {}
    for pid, samples in sampler.cpu.items():
        role = "driver (supervisor)" if pid == me else role_of_process(sampler.cmdline.get(pid, ""), actors, pid)
        cpu = cpu_between(samples, t0, t1) - (sampler_cpu if pid == me else 0.0)
        row = rows.setdefault(role, {"role": role, "group": group_of(role), "pids": [], "nice": [], "cpu_s": 0.0})
        row["pids"].append(pid)
        row["nice"] = sorted({*row["nice"], sampler.nice.get(pid, 0)})
        row["cpu_s"] += cpu
    rows["bench sampler"] = {"role": "bench sampler", "group": group_of("bench sampler"), "pids": [me],
                             "nice": [sampler.nice.get(me, 0)], "cpu_s": sampler_cpu}
    for row in rows.values():
        row["cores"], row["share"] = core_shares(row["cpu_s"], window, cores)
    ordered = sorted(rows.values(), key=lambda r: -r["cpu_s"])
    service = sum(r["cpu_s"] for r in ordered if r["role"] != "bench sampler")
    machine = last.machine_busy_s - first.machine_busy_s
    groups: dict[str, float] = {}
    for row in ordered:
        groups[row["group"]] = groups.get(row["group"], 0.0) + row["cpu_s"]
    held = {k: last.held[k] - first.held[k] for k in last.held}
    learner = learner_split(window, last.busy_s - first.busy_s, last.busy_cpu_s - first.busy_cpu_s, held)
    updates, env_steps = last.updates - first.updates, last.env_steps - first.env_steps
    learner_proc = rows.get("learner", {}).get("cpu_s", 0.0)
    learner.update(updates=updates, updates_per_s=updates / window,
                   process_cpu_s=learner_proc, process_cpu_outside_updates_s=learner_proc - learner["computing_cpu_s"],
                   cpu_ms_per_update=1e3 * learner["computing_cpu_s"] / updates if updates else None,
                   wall_ms_per_update=1e3 * learner["computing_s"] / updates if updates else None)
    return {"window_s": window, "window_from_start_s": [t0 - sampler.supervisor.clock.started,
                                                        t1 - sampler.supervisor.clock.started],
            "cores": cores, "env_steps": env_steps, "env_steps_per_s": env_steps / window, "roles": ordered,
            "groups": {g: {"cpu_s": c, "cores": c / window, "share": c / (window * cores)} for g, c in groups.items()},
            "service_cpu_s": service, "machine_cpu_s": machine, "rest_of_machine_cpu_s": max(0.0, machine - service
                                                                                              - sampler_cpu),
            "learner": learner}


# ----------------------------------------------------------------------------- main
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=DEFAULT_SECONDS,
                        help=f"the service's budget, run.max_seconds (default {DEFAULT_SECONDS}; make run: 300)")
    parser.add_argument("--config", default="configs/spread_maddpg.toml", help="make run's config (default)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], help="more config overrides k=v")
    parser.add_argument("--inline-rounds", type=int, default=7, help="interleaved rounds of the inline costs (0: skip)")
    parser.add_argument("--inline-updates", type=int, default=30, help="updates per round of the inline costs")
    parser.add_argument("--run-dir", default="runs/bench_service_breakdown")
    parser.add_argument("--out", default=DEFAULT_OUT, help=f"the JSON (default {DEFAULT_OUT}; '' = none)")
    args = parser.parse_args(argv)

    import torch

    from cmcl.config import load_config
    from cmcl.config.toml_io import dump_toml
    from cmcl.run.rundir import RunDirectory

    torch.set_num_threads(1)
    load_before = os.getloadavg()
    inline = None
    if args.inline_rounds > 0:
        from bench.learner_throughput import inline_update_seconds

        inline, _ = inline_update_seconds(args.inline_rounds, args.inline_updates)
        gc.collect()
        print(f"inline, one core: MADDPG update {1e3 * inline['maddpg']:.2f} ms ({1 / inline['maddpg']:.1f} "
              f"updates/s), CMCL update {1e3 * inline['cmcl']:.2f} ms ({1 / inline['cmcl']:.1f} updates/s)")
    overrides = [*MAKE_RUN, f"run.max_seconds={args.seconds:g}", "service.metrics_port=0", *args.overrides,
                 f"run.dir={args.run_dir}"]
    config = load_config(args.config, overrides)
    run = RunDirectory.create(args.run_dir, config, overwrite=True)
    code = provenance(dump_toml(config))  # the code as imported, before the run (the tree may change during it)
    cores = psutil.cpu_count()
    with LoadSampler(every_s=5.0) as load:
        sampler, actors, summary = run_service(config, run, args.seconds)
    result = breakdown(sampler, actors, cores)
    print(f"config {args.config} {overrides}; {cores} cores; load average before {load_before[0]:.2f}")
    print_table(result)
    print_summary(result, inline, load.summary())
    record = {"command": " ".join(["bench/service_breakdown.py", *(argv if argv is not None else sys.argv[1:])]),
              "config": args.config, "overrides": overrides, "seconds": args.seconds,
              "inline_seconds_per_update": inline,
              "inline": {"rounds": args.inline_rounds, "updates": args.inline_updates},
              "breakdown": result, "load": {**load.summary(), "before": [round(x, 2) for x in load_before]},
              "run": {k: summary.get(k) for k in ("episodes", "env_steps", "updates", "elapsed_s", "solved",
                                                  "failures", "hung", "checkpoint_seconds", "learner_held_s")},
              "provenance": code}
    if args.out:
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(record, indent=1, default=float) + "\n")
        print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

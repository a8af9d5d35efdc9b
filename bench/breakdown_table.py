"""The text bench/service_breakdown.py prints from its breakdown (the dict of `breakdown()` there, also the JSON's
"breakdown"): a table with one row per role, then totals, the CPU by group and the learner's time split; and the
summary against the inline costs.

Units: CPU seconds in the window (`CPU s`); `cores` = CPU s per wall second of the window, of one core (2.0 = two
cores busy); `share` = of all the machine's cores together; `ms/upd` = CPU milliseconds per learner update in the
window. Prints to stdout only.
"""

from __future__ import annotations

from typing import Any

from bench.breakdown_sampling import core_shares


def print_table(result: dict[str, Any]) -> None:
    """The table of a breakdown: the window, one row per role (pids, nice values, CPU s, cores, share, ms/upd), the
    totals (the service, the whole machine, the rest of the machine), the CPU by group and the learner's split."""
    window, cores = result["window_s"], result["cores"]
    print(f"\nwindow: {window:.1f} s of steady state (from {result['window_from_start_s'][0]:.1f} s after the "
          f"supervisor started, the learner's first update, to the budget's end); {cores} cores")
    print(f"{'role':34s} {'pids':>4s} {'nice':>6s} {'CPU s':>8s} {'cores':>6s} {'share':>6s} {'ms/upd':>8s}")
    updates = result["learner"]["updates"]

    def per_update(cpu: float) -> str:
        return f"{1e3 * cpu / updates:8.2f}" if updates else f"{'-':>8s}"

    for row in result["roles"]:
        print(f"{row['role']:34s} {len(row['pids']):4d} {','.join(map(str, row['nice'])):>6s} {row['cpu_s']:8.1f} "
              f"{row['cores']:6.2f} {100 * row['share']:5.1f}% {per_update(row['cpu_s'])}")
    for label, cpu in (("all of the service (no sampler)", result["service_cpu_s"]),
                       ("the whole machine", result["machine_cpu_s"]),
                       ("rest of the machine (other work)", result["rest_of_machine_cpu_s"])):
        used, share = core_shares(cpu, window, cores)
        print(f"{label:34s} {'':4s} {'':>6s} {cpu:8.1f} {used:6.2f} {100 * share:5.1f}% "
              f"{per_update(cpu) if label.startswith('all') else ''}".rstrip())
    print("\nby group:")
    for group, g in sorted(result["groups"].items(), key=lambda kv: -kv[1]["cpu_s"]):
        print(f"  {group:32s} {g['cpu_s']:8.1f} CPU s  {g['cores']:5.2f} cores  {100 * g['share']:5.1f}% of {cores}"
              f"  {per_update(g['cpu_s'])} CPU ms per update")
    ln = result["learner"]
    print(f"\nlearner: {ln['updates']:.0f} updates in the window, {ln['updates_per_s']:.1f} updates/s; rollouts "
          f"{result['env_steps_per_s']:.0f} env steps/s")
    print(f"  computing (inside update calls) {ln['computing_s']:7.1f} s  {100 * ln['computing_share']:5.1f}%   "
          f"of which on the CPU {ln['computing_cpu_s']:.1f} s, descheduled {ln['computing_off_cpu_s']:.1f} s")
    print(f"  idle                            {ln['idle_s']:7.1f} s  {100 * ln['idle_share']:5.1f}%")
    for key, label in (("held_env_steps", "no call: held by env steps (data)"),
                       ("held_scores", "no call: held by scores"),
                       ("held_checkpoint", "no call: checkpoint"), ("held_warmup", "no call: warm-up"),
                       ("held_other", "no call: other"), ("waiting_with_call", "a call in flight (batch / feedback)")):
        print(f"    {label:36s}{ln[key + '_s']:7.1f} s  {100 * ln[key + '_share']:5.1f}%")
    if ln["cpu_ms_per_update"] is not None:
        print(f"  per update: {ln['wall_ms_per_update']:.2f} ms wall, {ln['cpu_ms_per_update']:.2f} ms CPU in update "
              f"calls; learner process CPU outside update calls {ln['process_cpu_outside_updates_s']:.1f} s "
              f"(Ray's threads in it: receiving batches, sending feedback and weights)")


def print_summary(result: dict[str, Any], inline: dict[str, float] | None, load: dict[str, Any]) -> None:
    """The summary of a breakdown: the learner's updates/s against one core's (`inline`: seconds per inline update,
    keys "maddpg" and "cmcl"; None when not measured), the service's cores and CPU ms per update, the learner's
    computing / idle shares, the cores of each group, and the rest of the machine with `load` (the LoadSampler's
    summary: "load_mean", "load_max")."""
    ln, groups, cores = result["learner"], result["groups"], result["cores"]
    print("\nsummary:")
    if inline:
        print(f"  the learner ran {ln['updates_per_s']:.1f} updates/s where one core alone gives "
              f"{1 / inline['maddpg']:.1f} (an inline MADDPG update, {1e3 * inline['maddpg']:.2f} ms) and "
              f"{1 / inline['cmcl']:.1f} (an inline CMCL update with its teachers, ICM and scoring, "
              f"{1e3 * inline['cmcl']:.2f} ms), measured in this process before the service")
    else:
        print(f"  the learner ran {ln['updates_per_s']:.1f} updates/s (inline costs not measured: --inline-rounds 0)")
    service_ms = 1e3 * result["service_cpu_s"] / ln["updates"] if ln["updates"] else float("nan")
    print(f"  the service used {result['service_cpu_s'] / result['window_s']:.2f} cores, {service_ms:.1f} CPU ms per "
          f"learner update in all (the learner's own update calls: {ln['cpu_ms_per_update'] or float('nan'):.1f})")
    print(f"  the learner computed {100 * ln['computing_share']:.0f}% of the window and was idle "
          f"{100 * ln['idle_share']:.0f}% (held by env steps {100 * ln['held_env_steps_share']:.0f}%, by scores "
          f"{100 * ln['held_scores_share']:.0f}%, checkpoints {100 * ln['held_checkpoint_share']:.0f}%, with a call in "
          f"flight {100 * ln['waiting_with_call_share']:.0f}%)")
    for group, g in sorted(groups.items(), key=lambda kv: -kv[1]["cpu_s"]):
        print(f"  {group}: {g['cores']:.2f} cores ({100 * g['share']:.0f}% of {cores})")
    rest = result["rest_of_machine_cpu_s"] / result["window_s"]
    print(f"  rest of the machine (other sessions' work): {rest:.2f} cores; 1-minute load average during the run "
          f"{load['load_mean']} mean, {load['load_max']} max")

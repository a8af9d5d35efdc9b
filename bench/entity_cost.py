"""What one MADDPG update costs with entity networks against the paper's per-agent networks.

One `MADDPG.update` on a per-owner minibatch [N, S, N, ...] of random rows (S = 128 by default), per-agent
(`maddpg.networks = "per_agent"`) and entity networks (`"entity"`, cmcl.learners.entity.nets) built side by side in
this process and timed in interleaved rounds (the machine is shared: absolute times are noisy, the ratio is the
measure). Printed: median ms per update of each, ``ratio: X`` = entity / per-agent, and the same ratio of the
entity learner on the previous ops (`entity_reference`: `EntityEncoder.fused = False`, StackedLinear + relu_ and
the advanced-indexing critic views instead of cmcl.learners.entity.ops / entity_views; the same numbers to float32's
last bits) and as it ran before the fused entity kernels (`before_issue_38`: those ops and the old actor step).
``--nearest K`` adds the entity networks that read only the K nearest entities of each kind
(maddpg.entity_nearest, off by default); ``--assignment BETA`` the entity learner with maddpg.assignment_loss = BETA
(cmcl.learners.entity.assignment: the per-row assignment solver and the auxiliary loss in the actor step; off by
default);
``--holder`` the entity learner with maddpg.entity_holder (every landmark's holder margin as one more entity feature,
cmcl.learners.entity.holder; off by default), and with it under maddpg.holder_rule = "seated" (an agent seated on a
landmark holds only that one).
``--profile`` also prints where an update spends its time (torch.profiler, by phase and by op).

Run: .venv/bin/python bench/entity_cost.py [--agents 8] [--batch 128] [--nearest 3] [--assignment 1] [--holder]
     [--profile]
The whole inline update (sampling included) at N = 4, 8, 16: bench/scale.py --algorithm maddpg.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cmcl.envs.entities import spread_layout  # noqa: E402
from cmcl.learners.entity.nets import EntityEncoder  # noqa: E402
from cmcl.learners.maddpg import MADDPG  # noqa: E402
from cmcl.learners.nets import joint_input  # noqa: E402

PHASES = ("_critic_step", "_td_targets_t", "_actor_step")  # MADDPG methods timed as profiler phases


def learners(n: int, nearest: int, assignment: float = 0.0, holder: bool = False) -> dict[str, MADDPG]:
    """Navigation's learners for N agents: per-agent, entity (and entity with the K nearest entities, entity with
    the assignment loss of weight `assignment`, entity with the holder margin)."""
    layout = spread_layout(n)
    cells = {"per_agent": MADDPG(n, layout.obs_dim, 2, seed=0),
             "entity": MADDPG(n, layout.obs_dim, 2, seed=0, networks="entity", entity_layout=layout),
             "entity_reference": reference_ops(MADDPG(n, layout.obs_dim, 2, seed=0, networks="entity",
                                                      entity_layout=layout)),
             "entity_before": before_issue_38(reference_ops(MADDPG(n, layout.obs_dim, 2, seed=0, networks="entity",
                                                                   entity_layout=layout)))}
    if nearest:
        cells[f"entity_nearest{nearest}"] = MADDPG(n, layout.obs_dim, 2, seed=0, networks="entity",
                                                   entity_layout=layout, entity_nearest=nearest)
    if assignment:
        cells["entity_assignment"] = MADDPG(n, layout.obs_dim, 2, seed=0, networks="entity", entity_layout=layout,
                                            assignment_loss=assignment)
    if holder:
        cells["entity_holder"] = MADDPG(n, layout.obs_dim, 2, seed=0, networks="entity", entity_layout=layout,
                                        entity_holder=True)
        cells["entity_holder_seated"] = MADDPG(n, layout.obs_dim, 2, seed=0, networks="entity", entity_layout=layout,
                                               entity_holder=True, holder_rule="seated")
    return cells


def reference_ops(m: MADDPG) -> MADDPG:
    """The entity learner on the reference ops (``EntityEncoder.fused = False``: StackedLinear, einsum, softmax) instead
    of the fused kernels of cmcl.learners.entity.ops; the same numbers to float32's last bits."""
    for net in (m.actor, m.critic, m.target_actor, m.target_critic):
        for module in net.modules():
            if isinstance(module, EntityEncoder):
                module.fused = False
    return m


def before_issue_38(m: MADDPG) -> MADDPG:
    """The entity learner before the fused kernels: the actor step's Q on the joint input (pi written into the
    joint action, the backward pass through every entity slot); the same numbers (tests/test_entity_nets.py)."""
    own_mask = torch.eye(m.num_agents, dtype=torch.bool).view(m.num_agents, 1, m.num_agents, 1)

    def joint_q(obs, act, own_act, count=None):
        joint = torch.where(own_mask, own_act.unsqueeze(2), act)
        return m._q(m.critic, joint_input(obs, joint), None, count)

    m.critic.q_own_action = joint_q
    return m


def batch(n: int, s: int, obs_dim: int) -> dict[str, torch.Tensor]:
    """A per-owner minibatch of random rows (positions in [-1, 1], actions in [-1, 1])."""
    gen = torch.Generator().manual_seed(0)
    return {"obs": torch.rand(n, s, n, obs_dim, generator=gen) * 2 - 1,
            "act": torch.rand(n, s, n, 2, generator=gen) * 2 - 1,
            "rew": torch.randn(n, s, n, generator=gen),
            "next_obs": torch.rand(n, s, n, obs_dim, generator=gen) * 2 - 1}


def profile(label: str, m: MADDPG, rows: dict[str, torch.Tensor], updates: int = 5) -> None:
    """torch.profiler over `updates` updates: ms per update of each phase, then the ops by self time."""
    from torch.profiler import ProfilerActivity, record_function
    from torch.profiler import profile as torch_profile

    def timed(name, method):
        def run(*args, **kwargs):
            with record_function(f"phase {name}"):
                return method(*args, **kwargs)
        return run

    for name in PHASES:
        setattr(m, name, timed(name, getattr(m, name)))
    joint_actions = m._joint_actions

    def actions(net, *args, **kwargs):  # the target actions of the TD targets, timed apart
        name = "target actor on next_obs" if net is m.target_actor else "actor"
        return timed(name, joint_actions)(net, *args, **kwargs)

    m._joint_actions = actions
    try:
        with torch_profile(activities=[ProfilerActivity.CPU]) as prof:
            for _ in range(updates):
                m.update(rows)
    finally:
        for name in (*PHASES, "_joint_actions"):
            delattr(m, name)
    events = prof.key_averages()
    total = sum(e.self_cpu_time_total for e in events)
    print(f"{label}: {total / 1e3 / updates:.1f} ms per update under the profiler")
    for e in sorted((e for e in events if e.key.startswith("phase")), key=lambda e: -e.cpu_time_total):
        print(f"  {e.key:40s} {e.cpu_time_total / 1e3 / updates:7.1f} ms  {e.cpu_time_total / total:5.0%}")
    for e in sorted((e for e in events if not e.key.startswith("phase")), key=lambda e: -e.self_cpu_time_total)[:12]:
        print(f"  {e.key:40s} {e.self_cpu_time_total / 1e3 / updates:7.1f} ms  {e.self_cpu_time_total / total:5.0%}"
              f"  ({e.count // updates} calls)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--agents", type=int, default=8)
    parser.add_argument("--batch", type=int, default=128)
    parser.add_argument("--rounds", type=int, default=9)
    parser.add_argument("--updates", type=int, default=5)
    parser.add_argument("--nearest", type=int, default=0, metavar="K")
    parser.add_argument("--assignment", type=float, default=0.0, metavar="BETA")
    parser.add_argument("--holder", action="store_true")
    parser.add_argument("--profile", action="store_true")
    args = parser.parse_args()
    torch.set_num_threads(1)
    cells = learners(args.agents, args.nearest, args.assignment, args.holder)
    rows = batch(args.agents, args.batch, cells["per_agent"].obs_dim)
    for m in cells.values():  # warm-up
        m.update(rows)
    seconds: dict[str, list[float]] = {name: [] for name in cells}
    for _ in range(args.rounds):
        for name, m in cells.items():
            t0 = time.perf_counter()
            for _ in range(args.updates):
                m.update(rows)
            seconds[name].append((time.perf_counter() - t0) / args.updates)
    median = {name: statistics.median(v) for name, v in seconds.items()}
    print(f"N = {args.agents}, batch {args.batch}: one MADDPG update, median of {args.rounds} interleaved rounds of "
          f"{args.updates}: " + ", ".join(f"{name} {1e3 * t:.1f} ms" for name, t in median.items()))
    for name in cells:
        if name != "per_agent":
            print(f"ratio{'' if name == 'entity' else ' ' + name}: {median[name] / median['per_agent']:.2f}")
    if "entity_assignment" in median:
        print(f"assignment loss: +{1e3 * (median['entity_assignment'] - median['entity']):.1f} ms per entity update "
              f"({median['entity_assignment'] / median['entity']:.2f}x)")
    if "entity_holder" in median:
        print(f"holder margin: +{1e3 * (median['entity_holder'] - median['entity']):.1f} ms per entity update "
              f"({median['entity_holder'] / median['entity']:.2f}x)")
        print(f"seated rule: +{1e3 * (median['entity_holder_seated'] - median['entity_holder']):.1f} ms per entity "
              f"update with the margin ({median['entity_holder_seated'] / median['entity_holder']:.2f}x)")
    if args.profile:
        for name, m in cells.items():
            profile(name, m, rows)


if __name__ == "__main__":
    main()

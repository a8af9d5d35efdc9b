"""Scale past the paper's N = 4: what one update costs, and how learning goes, at N = 4, 8 and 16 agents.

Cost (default): for each N and each network kind (NETWORKS: per-agent networks, the paper's; `maddpg.
networks = "shared"`; and that plus `teachers.networks = "shared"`, one teacher network per fold; and
`maddpg.networks = "entity"`, one attention actor and critic whose size does not depend on N),
the service's roles of cooperative navigation (N agents, N landmarks), built in this process as `--runner inline`
runs them (bench/learner_throughput.py `FilledRoles`), fill the buffer to its capacity by their own policy, then are
timed over interleaved rounds of learner updates (everything the roles do per update at the defaults: the MADDPG
step, and for CMCL the teacher and ICM steps with their scoring calls and the priority recompute). Printed:
median milliseconds per update, parameter counts of the actors + critics (+ teachers), and the ratio of each
cell against N = 4 per-agent measured in the same process.

Learning (`--learn EPISODES`): one inline training run (`python -m cmcl train --runner inline`) per (N, sharing,
seed) with early stop off, reporting the final moving-average coverage and success, episodes to MA 0.5 / 0.9 and
wall seconds. Writes one JSON per run to `--out` (default lab/results/scale/); a rerun skips finished runs and
resumes an interrupted one from its newest checkpoint (`python -m cmcl resume`; every service.checkpoint_every_s
seconds; its clock goes on from there).

Run: .venv/bin/python bench/scale.py [--algorithm cmcl] [--agents 4 8 16] [--before-issue-38]
     .venv/bin/python bench/scale.py --learn 20000 --agents 8 --seeds 0 1 2
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.learner_throughput import FilledRoles, filled_loop  # noqa: E402
from cmcl.run.provenance import provenance  # noqa: E402
from cmcl.run.rundir import RunDirectory  # noqa: E402
from experiments.measures import WINDOW, first_reaching  # noqa: E402

NETWORKS = {  # network kind -> (maddpg.networks, teachers.networks = "shared")
    "own": ("per_agent", False),  # per-agent actors, critics and (agent, fold) teachers: the paper's
    "shared": ("shared", False),  # one actor and one critic for all agents
    "shared_teachers": ("shared", True),  # ... and one teacher per fold for all agents
    "entity": ("entity", False),  # entity actor and critic (cmcl.learners.entity.nets); per-agent teachers
}


def overrides(n: int, kind: str) -> list[str]:
    """Config overrides of the navigation preset for N agents (and N landmarks) with the networks of `kind`."""
    maddpg, teachers = NETWORKS[kind]
    return [f"env.num_agents={n}", f"maddpg.networks={maddpg}",
            f"teachers.networks={'shared' if teachers else 'per_agent'}"]


def parameter_counts(loop: FilledRoles) -> tuple[int, int]:
    """Trainable parameters of (the learner's actors + critics, the teacher critics; 0 without teachers)."""
    learner = sum(p.numel() for m in (loop.maddpg.actor, loop.maddpg.critic) for p in m.parameters())
    teachers = loop.teachers
    modules = [] if teachers is None else [m for m in vars(teachers).values() if hasattr(m, "parameters")]
    return learner, sum(p.numel() for m in modules for p in m.parameters())


def update_cost(algorithm: str, agents: list[int], rounds: int, updates: int, networks: list[str],
                before: bool = False) -> None:
    """Median ms per update for every (N, network kind) cell, interleaved, and the ratio to the first
    cell (the smallest N with the first kind); `before`: also the entity learner before the fused kernels
    (bench.entity_cost.before_issue_38: the same numbers, the old actor step), as kind "entity_before"."""
    cells = {(n, kind): filled_loop(algorithm, overrides(n, kind)) for n in agents for kind in networks}
    if before:
        from bench.entity_cost import before_issue_38

        for n in agents:
            cells[(n, "entity_before")] = loop = filled_loop(algorithm, overrides(n, "entity"))
            before_issue_38(loop.maddpg)
    seconds: dict[tuple[int, str], list[float]] = {cell: [] for cell in cells}
    for _ in range(rounds):
        for cell, loop in cells.items():
            t0, done = time.perf_counter(), 0
            while done < updates:  # in learner calls of service.updates_per_call updates
                done += loop.update()
            seconds[cell].append((time.perf_counter() - t0) / done)
    median = {cell: statistics.median(v) for cell, v in seconds.items()}
    peer = median[(min(agents), networks[0])]
    print(f"{algorithm}: one update at the defaults (the roles in one process), median of {rounds} rounds of "
          f"~{updates}")
    print(f"| N | networks | ms per update | actor + critic parameters | teacher parameters | "
          f"cost / N={min(agents)} {networks[0]} |")
    print("| --- | --- | --- | --- | --- | --- |")
    for (n, kind), loop in cells.items():
        learner, teachers = parameter_counts(loop)
        print(f"| {n} | {kind} | {1e3 * median[(n, kind)]:.2f} | {learner:,} | "
              f"{teachers:,} | {median[(n, kind)] / peer:.2f} |")


def learn(algorithm: str, agents: list[int], seeds: list[int], episodes: int, out: Path,
          networks: list[str]) -> None:
    """One inline run per (N, sharing, seed), each in its own process; one summary JSON per run (resumable)."""
    out.mkdir(parents=True, exist_ok=True)
    for n in agents:
        for kind in networks:
            for seed in seeds:
                name = f"{algorithm}_n{n}_{kind}_s{seed}"
                if (out / f"{name}.json").exists():
                    continue
                run_dir = out / "runs" / name
                if run_dir.exists() and RunDirectory.open(run_dir).runners():
                    args = [sys.executable, "-m", "cmcl", "resume", str(run_dir), "--runner", "inline", "--quiet"]
                else:
                    settings = [f"run.dir={run_dir}", f"run.seed={seed}", f"run.episodes={episodes}",
                                "run.stop_coverage=0", *overrides(n, kind)]
                    args = [sys.executable, "-m", "cmcl", "train", "--runner", "inline", "--config",
                            f"{ROOT}/configs/spread_{algorithm}.toml", "--quiet", "--overwrite",
                            *[a for kv in settings for a in ("--set", kv)]]
                subprocess.run(args, check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
                rows = list(RunDirectory.open(run_dir).rows("episode"))
                coverage = np.array([r["coverage"] for r in rows], np.float64)
                success = np.array([r["success"] for r in rows], np.float64)
                summary = {"algorithm": algorithm, "agents": n, "networks": kind,
                           "shared": NETWORKS[kind][0] == "shared", "shared_teachers": NETWORKS[kind][1], "seed": seed,
                           "episodes": len(coverage), "wall_s": rows[-1]["elapsed_s"],  # resumes included
                           "final_ma_coverage": float(coverage[-WINDOW:].mean()),
                           "final_ma_success": float(success[-WINDOW:].mean()),
                           "episodes_to_50": first_reaching(coverage, 0.5),
                           "episodes_to_90": first_reaching(coverage, 0.9)}
                summary["provenance"] = provenance()
                (out / f"{name}.json").write_text(json.dumps(summary, indent=1))
                print(json.dumps(summary), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--algorithm", default="cmcl", choices=["maddpg", "per", "acl", "cmcl"])
    parser.add_argument("--agents", type=int, nargs="+", default=[4, 8, 16])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--updates", type=int, default=20)
    parser.add_argument("--learn", type=int, default=0, metavar="EPISODES", help="train instead of timing")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--networks", nargs="+", default=list(NETWORKS), choices=list(NETWORKS),
                        help="network kinds (NETWORKS; with --learn, two processes can split them)")
    parser.add_argument("--out", default=str(ROOT / "lab" / "results" / "scale"))
    parser.add_argument("--before-issue-38", action="store_true",
                        help="cost: also time the entity learner before the fused kernels (bench/entity_cost.py)")
    args = parser.parse_args()
    if args.learn:
        learn(args.algorithm, args.agents, args.seeds, args.learn, Path(args.out), args.networks)
    else:
        update_cost(args.algorithm, args.agents, args.rounds, args.updates, args.networks, args.before_issue_38)


if __name__ == "__main__":
    main()

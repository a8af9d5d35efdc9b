"""The quoted numbers of the time-to-solve grids (lab.report.quoted), the blocks of docs/LEARNING.md: tts (the
algorithms grid), schedule (the schedule grid), ttstag (predator-prey) and refactoring (the service runs after the
one-implementation refactoring, REFACTORING under the results root, against the algorithms grid's service runs).
Reads only those runs' summaries, as quoted_blocks passes them.
"""

from __future__ import annotations

from typing import Any

from experiments.labels import LABEL, ORDER
from lab.report.quoted_words import NO_RUNS, joined, span
from lab.report.tables import SOLVE_HEADER, solve_cells, solve_groups, solve_tag_table

# the service runs after the one-implementation refactoring (`python -m experiments run algorithms --modes service
# --algorithms cmcl maddpg --seeds 0 1 2 --out lab/results/time_to_solve_issue8`), under the results root
REFACTORING = "time_to_solve_issue8"


def reached_text(rs: list[dict[str, Any]]) -> str:
    """'2 of 3 seeds (9,301 and 10,436 episodes, 149 and 166 s; seed 0 ended at a moving average of 0.76, held-out
    coverage 0.77)' for the runs of one cell of a time-to-solve grid."""
    got = sorted((r for r in rs if r["episodes_to_90"] is not None), key=lambda r: r["episodes_to_90"])
    missed = sorted((r for r in rs if r["episodes_to_90"] is None), key=lambda r: r["seed"])
    parts = []
    if len(got) > 2:
        parts.append(f"{got[0]['episodes_to_90']:,}–{got[-1]['episodes_to_90']:,} episodes, "
                     f"{span([r['seconds_to_90'] for r in got], 0)} s")
    elif got:
        parts.append(joined([f"{r['episodes_to_90']:,}" for r in got]) + " episodes, "
                     + joined([f"{r['seconds_to_90']:.0f}" for r in got]) + " s")
    if got and not missed:
        parts.append(f"held-out coverage {span([r['held_out_coverage'] for r in got], 2)}")
    parts += [f"seed {r['seed']} ended at a moving average of {r['final_ma_coverage']:.2f}, held-out coverage "
              f"{r['held_out_coverage']:.2f}" for r in missed]
    return f"{len(got)} of {len(rs)} seeds ({'; '.join(parts)})"


def refactoring_summary(after: list[dict[str, Any]], before: list[dict[str, Any]]) -> str:
    """docs/LEARNING.md's sentence on the service runs after the one-implementation refactoring, against the
    algorithms grid's service runs of the same algorithms and seeds."""
    algorithms = [a for a in ORDER if any(r["algorithm"] == a for r in after)]
    cells = {a: [r for r in after if r["algorithm"] == a] for a in algorithms}
    earlier = {a: [r for r in before if r.get("grid") == "algorithms" and r.get("mode") == "service"
                   and r["algorithm"] == a and r["seed"] in {x["seed"] for x in cells[a]}] for a in algorithms}
    text = ", ".join(f"service {LABEL[a]} reached MA 0.9 on {reached_text(cells[a])}" for a in algorithms)
    counts = {a: (sum(r["episodes_to_90"] is not None for r in rs), len(rs)) for a, rs in earlier.items()}
    now = {a: (sum(r["episodes_to_90"] is not None for r in rs), len(rs)) for a, rs in cells.items()}
    return (text[0].upper() + text[1:] + ". " + ("The same counts as before it" if counts == now else
                                                  "Before it (the algorithms grid's service runs)")
            + " (" + ", ".join(f"{LABEL[a]} {k} of {n}" for a, (k, n) in counts.items()) + ").")


def solve_tables(runs: list[dict[str, Any]]) -> dict[str, str]:
    """docs/LEARNING.md's tables of the time-to-solve grids: tts (the algorithms grid per mode and algorithm), schedule
    (the schedule grid per update_every and batch, its MADDPG cell at the default schedule completed by the algorithms
    grid's inline MADDPG runs of the seeds it lacks: the same configuration) and ttstag (predator-prey, with what its
    ranges show)."""
    algorithms = [r for r in runs if r.get("grid") == "algorithms"]
    schedule = [r for r in runs if r.get("grid") == "schedule"]
    have = {(r["algorithm"], r["update_every"], r["batch_size"], r["seed"]) for r in schedule}
    schedule += [r for r in algorithms if r.get("mode", "inline") == "inline"
                 and (r["algorithm"], r["update_every"], r["batch_size"], r["seed"]) not in have
                 and any((r["algorithm"], r["update_every"], r["batch_size"]) == h[:3] for h in have)]
    out = {}
    for name, rs, fields in (("tts", algorithms, ("mode", "algorithm")),
                             ("schedule", schedule, ("algorithm", "update_every", "batch_size"))):
        groups = solve_groups(rs, fields)
        header = " | ".join("batch" if f == "batch_size" else f for f in fields)
        rows = [f"| {' | '.join(str(k) for k in key)} | {solve_cells(groups[key])} |" for key in sorted(groups)]
        out[name] = "\n".join([f"| {header} | {SOLVE_HEADER}", "| --- " * (len(fields) + 8) + "|", *rows]) \
            if rows else NO_RUNS
    tag = [r for r in runs if r.get("task") == "tag"]
    out["ttstag"] = NO_RUNS
    if tag:
        by_alg = {a: [r for r in tag if r["algorithm"] == a] for a in sorted({r["algorithm"] for r in tag})}
        trained = {a: [r["win_vs_trained_prey"] for r in rs] for a, rs in by_alg.items()}
        random_prey, random = ([r[k] for r in tag] for k in ("win_vs_random_prey", "random_vs_random"))
        overlap = all(min(max(x), max(y)) >= max(min(x), min(y)) for x in trained.values() for y in trained.values())
        seeds = span([len(rs) for rs in by_alg.values()], 0)
        out["ttstag"] = solve_tag_table(tag) + "\n\n" + (
            f"Trained predators beat random prey {'clearly ' if min(random_prey) > max(random) else ''}with every "
            f"algorithm and seed ({span(random_prey, 2)} against {span(random, 2)} for random predators), and beat the "
            f"MADDPG prey trained beside them in {span([w for ws in trained.values() for w in ws], 2)} of rounds. "
            + (f"The ranges of the {len(by_alg)} algorithms overlap over {seeds} seeds: an order between them is not "
               "shown." if overlap else f"Over {seeds} seeds no test is run: an order between them is not shown."))
    return out

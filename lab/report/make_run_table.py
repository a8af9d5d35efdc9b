"""`make run` measured: the README's table of the make_run grid's summaries, one row per seed, and the
tally under it. Every number the README gives of `make run` comes from here (lab/tests/test_make_run_table.py checks
the README's block against the committed summaries).

Seconds are the run's training clock when its 100-episode moving-average coverage first reached 0.9 (the run stops
there); a run that did not get there is counted as censored after every time that did (stats.kaplan_meier): true
for a run that used its 300 s; a run whose episode budget ran out first stops earlier (the 20,000 episodes of the
budget before 32bb9d1 did so on a fast machine: at 400bdbe at 155 s, after the last time that got there, 126 s; since
then the budget is 60,000, MAKE_RUN_EPISODES). The median is Kaplan-Meier over seeds.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from experiments.provenance import code_version
from experiments.store import ResultsStore
from lab.report.stats import kaplan_meier, median_text


def earlier_runs(folder: Path) -> list[dict[str, Any]]:
    """The summaries of every earlier measurement kept under the make_run grid's folder: <folder>/earlier/<commit>/
    (one results folder per measurement, named by its commit), oldest folder name first."""
    return [r for sub in sorted(p for p in (folder / "earlier").glob("*") if p.is_dir())
            for r in ResultsStore(sub).load()]


def make_run_table(runs: list[dict[str, Any]], config: str, earlier: list[dict[str, Any]] = ()) -> str:
    """The runs of today's `make run` (those of `runs` whose config file is `config`), per seed: reached MA 0.9 or not,
    seconds and episodes to it, held-out coverage and success at the end, the training seconds, the mean load over the
    run, the code and the day it ran; then the tally over seeds, and one tally per earlier measurement: each config
    `make run` trained before (in `runs` or `earlier`), and each commit of the measurements moved to `earlier` (the
    make_run grid's folder's earlier/<commit>/, measured before, as on another machine: earlier_runs)."""
    before = [r for r in runs if r["config"] != config] + list(earlier)
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in before:
        groups.setdefault((r["config"], ((r.get("provenance") or {}).get("commit") or "")[:7]), []).append(r)
    earlier_lines = [f"Earlier, `make run` trained `configs/{c}`{measured(group)}: {tally(group)}"
                     for (c, _), group in sorted(groups.items(), key=lambda kv: first_day(kv[1]))]
    runs = sorted((r for r in runs if r["config"] == config), key=lambda r: r["seed"])
    if not runs:
        return "\n\n".join(["not measured yet", *earlier_lines])
    lines = ["| seed | reached MA 0.9 | seconds to MA 0.9 | episodes to MA 0.9 | held-out coverage | "
             "held-out success | training s | load (1-min mean) | code | measured |", "| --- " * 10 + "|"]
    for r in runs:
        reached = r.get("seconds_to_90") is not None
        load = (r.get("provenance") or {}).get("load_mean")
        lines.append(f"| {r['seed']} | {'yes' if reached else 'no'} | "
                     f"{r['seconds_to_90']:.0f} | {r['episodes_to_90']:,} | " if reached else
                     f"| {r['seed']} | no | — | — | ")
        lines[-1] += (f"{r['held_out_coverage']:.3f} | {r['held_out_success']:.3f} | {r['wall_s']:.0f} | "
                      f"{'—' if load is None else f'{load:.2f}'} | {code_version(r)} | "
                      f"{(r.get('provenance') or {}).get('measured_utc', '—')[:10]} |")
    lines += ["", tally(runs), *(part for line in earlier_lines for part in ("", line))]
    return "\n".join(lines)


def make_run_summary(runs: list[dict[str, Any]], config: str) -> str:
    """README.md's view of today's `make run` (those of `runs` whose config file is `config`): per seed, reached MA 0.9
    or not, seconds and episodes to it, held-out coverage and success; then the tally. No code, load or day: those are
    the record's (`make_run_table`, lab/RESULTS.md)."""
    runs = sorted((r for r in runs if r["config"] == config), key=lambda r: r["seed"])
    if not runs:
        return "not measured yet"
    lines = ["| seed | reached MA 0.9 | seconds to MA 0.9 | episodes to MA 0.9 | held-out coverage | "
             "held-out success |", "| --- " * 6 + "|"]
    for r in runs:
        reached = r.get("seconds_to_90") is not None
        lines.append((f"| {r['seed']} | yes | {r['seconds_to_90']:.0f} | {r['episodes_to_90']:,} | " if reached else
                      f"| {r['seed']} | no | — | — | ")
                     + f"{r['held_out_coverage']:.3f} | {r['held_out_success']:.3f} |")
    return "\n".join([*lines, "", tally(runs, code=False)])


def tally(runs: list[dict[str, Any]], code: bool = True) -> str:
    """How many of `runs` reached MA 0.9 within their budget (300 s of training; on a fast machine the episode budget
    can end a run first, and the tally says so), the Kaplan-Meier median time to it, and (`code`) the code they ran."""
    seconds = [r.get("seconds_to_90") for r in runs]
    reached = sum(s is not None for s in seconds)
    codes = ", ".join(sorted({code_version(r) for r in runs}))
    episodes = sorted({r["budget"] for r in runs if r.get("budget")})
    ended = [r for r in runs if r.get("seconds_to_90") is None and r.get("episodes", 0) >= r.get("budget", 1e12)]
    missed, at = len(runs) - reached, "–".join(sorted({f"{r['wall_s']:.0f}" for r in ended}, key=float))
    budget = (f"the budget, 300 s of training or {'/'.join(f'{e:,}' for e in episodes)} episodes, whichever ends "
              f"first ({'the' if len(ended) == missed else f'{len(ended)} of the'} {missed} that did not ran out of "
              f"episodes first, at {at} s)") if ended else "the 300-second budget"
    return (f"{reached} of {len(runs)} seeds reached MA 0.9 within {budget}; Kaplan–Meier median time to "
            f"MA 0.9: {median_text(seconds, missing='not reached')}"
            + ("" if kaplan_meier(seconds)[0] is None else " s") + (f" (code {codes})." if code else "."))


def first_day(runs: list[dict[str, Any]]) -> str:
    """The earliest 'YYYY-MM-DD HH:MM' the runs were measured ('' when none recorded it)."""
    return min(((r.get("provenance") or {}).get("measured_utc") or "" for r in runs), default="")


def measured(runs: list[dict[str, Any]]) -> str:
    """' (measured 2026-12-05)' or ' (measured 2026-12-05 on <cpu model>)', '' when the runs did not record the day."""
    day = first_day(runs)[:10]
    cpus = sorted({((r.get("provenance") or {}).get("cpu") or {}).get("model", "") for r in runs} - {""})
    return f" (measured {day}{' on ' + ', '.join(cpus) if cpus else ''})" if day else ""

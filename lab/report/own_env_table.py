"""The own-environment grid's table (the `ownenvs` block of lab/RESULTS.md): each environment of
experiments.own_envs.OWN_ENVS, per runner and team, against the random policy on the same held-out episodes."""

from __future__ import annotations

from typing import Any

import numpy as np

from experiments.own_envs import OWN_ENVS


def _mean_sd(values: list[float], digits: int) -> str:
    x = np.asarray(values, dtype=np.float64)
    sd = f" ± {x.std(ddof=1):.{digits}f}" if x.size > 1 else ""
    return f"{x.mean():.{digits}f}{sd}"


def own_env_table(runs: list[dict[str, Any]]) -> str:
    """One row per (environment, runner, team): held-out return mean ± sd over the seeds, the random policy's,
    the team against random others (competing teams only), the seeds, episodes and wall seconds (means)."""
    lines = ["| environment | runner | team | held-out return (mean ± sd over seeds) | random policy | "
             "vs random others | seeds | episodes | wall s |", "| --- " * 9 + "|"]
    for name, env in OWN_ENVS.items():
        for mode in ("inline", "service"):
            rs = sorted((r for r in runs if r.get("env") == name and r.get("mode", "inline") == mode),
                        key=lambda r: r["seed"])
            if not rs:
                continue
            for team in rs[0]["held_out_return"]:
                versus = [r["vs_random_others_return"][team] for r in rs if env.competing]
                lines.append(
                    f"| {env.label} | {mode} | {team} | {_mean_sd([r['held_out_return'][team] for r in rs], 1)} | "
                    f"{_mean_sd([r['random_return'][team] for r in rs], 1)} | "
                    f"{_mean_sd(versus, 1) if versus else '–'} | {','.join(str(r['seed']) for r in rs)} | "
                    f"{np.mean([r['episodes'] for r in rs]):,.0f} | {np.mean([r['wall_s'] for r in rs]):.0f} |")
    return "\n".join(lines)
